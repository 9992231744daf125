"""A notebook-style tour of `import assist` (run top to bottom; CI runs it).

    python examples/python_quickstart.py SCENE.assist DATASET [OUT_DIR]
"""

import sys
from pathlib import Path

import numpy as np

import assist

scene_path, data = sys.argv[1], sys.argv[2]
out = Path(sys.argv[3] if len(sys.argv) > 3 else "quickstart-out")

# %% Load a trained scene and list its objects.
scene = assist.Scene.load(scene_path)
for n in scene.nodes:
    print(n["id"], n["label"], "centre", np.round(n["pose"][:3, 3], 3))

# %% Cameras: the dataset's, or an orbit around the objects.
cams = assist.Dataset.load(data).cameras
cam = cams[0]
print(cam, "intrinsics", cam.intrinsics)

# %% Render to numpy: colour, metric depth, instance ids.
frame = scene.render(cam)
rgb, depth, ids = frame["rgb"], frame["depth"], frame["instance"]
print("rgb", rgb.shape, "depth range", float(depth[depth > 0].min()), float(depth.max()),
      "objects in view", sorted(set(np.unique(ids)) - {0}))

# %% Edit in words; the resolved actions come back as dicts.
first = next(n for n in scene.nodes if not n["background"])
print(scene.apply(f"move the {first['label']} 5 cm left and rotate it 45 degrees"))

# %% ... or as actions, one undo step each call.
print(scene.apply([{"instance_id": first["id"], "operation": "scale", "config": {"factor": 1.2}}]))
scene.undo()

# %% What is under a pixel?
ys, xs = np.nonzero(scene.render(cam, outputs=["instance"])["instance"])
if len(xs):
    print("picked", scene.pick(cam, xs[0] + 0.5, ys[0] + 0.5))

# %% A small batch of orbit views, as a data loader would build it.
batch = np.stack([scene.render(c, outputs=["rgb"], width=64)["rgb"] for c in assist.orbit(scene, frames=4)])
print("batch", batch.shape, batch.dtype)

# %% Errors are Python exceptions carrying the library's message.
try:
    scene.apply("delete the giraffe")
except assist.AssistError as e:
    print("AssistError:", e)

# %% Save the edited scene (atomically; never over a folder assist did not write).
scene.save(out / "edited.assist", force=True)
print("saved", out / "edited.assist")
