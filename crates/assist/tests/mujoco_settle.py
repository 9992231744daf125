"""MuJoCo steps an exported scene (issue 47 item 2): every object rests on its support.

usage: mujoco_settle.py MJCF_DIR   (or imported: `settle(mjcf_dir, count)`)

Loads scene.xml, checks the bodies start at the nodes' poses with a mass, steps two
simulated seconds and checks every object stays within 1 cm of where it started (with
nothing under it, an object falls to -4 m in that time) and every base pad rests on at
least three contacts.
"""

import json
import os
import sys

import mujoco
import numpy as np


def settle(mjcf_dir, count=None):
    model = mujoco.MjModel.from_xml_path(os.path.join(mjcf_dir, "scene.xml"))
    index = json.load(open(os.path.join(mjcf_dir, "export.json")))
    nodes = index["nodes"]
    if count is not None:
        assert len(nodes) == count, (len(nodes), count)
    assert model.nbody == 1 + len(nodes), (model.nbody, len(nodes))
    assert model.nmesh == len(nodes)
    for k, node in enumerate(nodes):
        assert np.allclose(model.body_pos[k + 1], node["position_m"], atol=1e-5)
        assert model.body_mass[k + 1] > 0
    assert index["supports_m"], "no support under the objects"
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    start = data.xpos[1:].copy()
    for _ in range(int(round(2.0 / model.opt.timestep))):
        mujoco.mj_step(model, data)
    assert np.all(np.isfinite(data.qpos))
    moved = np.linalg.norm(data.xpos[1:] - start, axis=1)
    assert np.all(moved < 0.01), f"objects moved {moved} m in 2 s"
    # A flat base rests on its pad's corners (the box-box collider), not on one point.
    pads = 0
    for g in range(model.ngeom):
        if not model.geom(g).name.endswith("_pad"):
            continue
        pads += 1
        touching = [
            c
            for c in data.contact[: data.ncon]
            if g in (c.geom1, c.geom2)
        ]
        assert len(touching) >= 3, f"{model.geom(g).name}: {len(touching)} contacts"
    print(
        f"mujoco: {len(moved)} objects ({pads} on pads), largest move in 2 s {moved.max() * 1000:.2f} mm"
    )


if __name__ == "__main__":
    settle(sys.argv[1])
