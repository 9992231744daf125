"""Reads `assist export` outputs back as a user's tools do (run by tests/export_cli.rs).

usage: export_check.py CAPTURE OBJ_DIR PLY_DIR GLB_DIR POINTS_DIR MJCF_DIR URDF_DIR

- every OBJ loads in trimesh, is watertight with a positive volume, and lies inside the
  capture's ground-truth box of its object (grown by 25 % and 1 cm);
- the PLY and GLB meshes of each node have the OBJ's vertices and faces;
- the point clouds load with their points on the OBJ's surface;
- MuJoCo loads scene.xml and steps it for 2 s: every object stays within 1 cm of its
  pose, resting on the support slabs; the URDFs parse and name files that exist.
"""

import json
import os
import sys
import xml.etree.ElementTree as ET

import numpy as np
import trimesh

cap, obj_dir, ply_dir, glb_dir, pts_dir, mjcf_dir, urdf_dir = sys.argv[1:8]
instances = {i["id"]: i for i in json.load(open(os.path.join(cap, "transforms.json")))["instances"]}
index = json.load(open(os.path.join(obj_dir, "export.json")))
assert index["nodes"], index
checked = 0
for node in index["nodes"]:
    mesh = trimesh.load(os.path.join(obj_dir, node["file"]), force="mesh")
    assert len(mesh.faces) > 100, (node, len(mesh.faces))
    assert mesh.is_watertight, f"{node['file']} is not watertight"
    assert mesh.is_winding_consistent, node["file"]
    assert mesh.volume > 0, (node["file"], mesh.volume)
    assert mesh.visual.kind == "vertex", node["file"]
    # Inside the object's true box (world frame), grown a little.
    box = instances[node["id"]]["bbox"]
    rot = np.array(box["rotation"]).reshape(3, 3)
    local = (mesh.vertices - np.array(box["center"])) @ rot
    half = np.array(box["size"]) / 2 * 1.25 + 0.01
    outside = np.mean(np.any(np.abs(local) > half, axis=1))
    assert outside < 0.02, f"{node['file']}: {outside:.1%} of the vertices outside the true box"
    # The same mesh in the other formats.
    stem = os.path.splitext(node["file"])[0]
    ply = trimesh.load(os.path.join(ply_dir, stem + ".ply"), force="mesh", process=False)
    plain = trimesh.load(os.path.join(obj_dir, node["file"]), force="mesh", process=False)
    assert len(ply.faces) == len(plain.faces), (len(ply.faces), len(plain.faces))
    assert np.allclose(ply.vertices, plain.vertices, atol=1e-5)
    glb = trimesh.load(os.path.join(glb_dir, stem + ".glb"), force="mesh", process=False)
    assert len(glb.faces) == len(plain.faces)
    assert np.allclose(np.sort(glb.vertices, axis=0), np.sort(plain.vertices, axis=0), atol=1e-5)
    pts = trimesh.load(os.path.join(pts_dir, stem + ".ply"))
    assert isinstance(pts, trimesh.PointCloud), type(pts)
    # A sample of the points lies on the surface (brute force: no spatial index needed;
    # trimesh's point-triangle distance errs by ~1e-4 of the size on sliver triangles).
    tol = 5e-3 * np.ptp(plain.vertices, axis=0).max()
    tri = plain.triangles
    for p in pts.vertices[:: max(1, len(pts.vertices) // 40)]:
        near = trimesh.triangles.closest_point(tri, np.repeat(p[None], len(tri), axis=0))
        d = np.min(np.linalg.norm(near - p, axis=1))
        assert d < tol, (d, tol)
    checked += 1

from mujoco_settle import settle  # noqa: E402  (beside this script)

settle(mjcf_dir, checked)

urdf = ET.parse(os.path.join(urdf_dir, "scene.urdf")).getroot()
links = [l for l in urdf.findall("link") if l.get("name") != "world"]
assert len(links) == checked
for mesh in urdf.iter("mesh"):
    assert os.path.isfile(os.path.join(urdf_dir, mesh.get("filename"))), mesh.get("filename")
for link in links:
    assert float(link.find("inertial/mass").get("value")) > 0
    assert os.path.isfile(os.path.join(urdf_dir, link.get("name") + ".urdf"))
print(f"{checked} nodes: watertight OBJ inside their true boxes; PLY, GLB, points, MJCF, URDF read back")
