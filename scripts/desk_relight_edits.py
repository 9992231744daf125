"""Ground truth for relighting on desk: the 20 test views after edits that change how the
room's light falls on an object (issue 43), rendered by desk's own Cycles script.

desk's `render_desk.py` (in the dataset, read only) builds the scene and renders an edit;
this wrapper adds the edits it lacks and writes under --out instead of the dataset:
  rotate_mug     the mug turned 90° about z (its lit side faces away from the lamp)
  rotate_duck    the duck turned 180° about z
  move_teapot    the teapot carried to the table's corner under the lamp, so the light
                 falls on it from the other side

Usage (a venv with bpy 4.5 LTS, numpy and pillow from PyPI; CPU Cycles, ~20 s a view on 2
cores at desk's 96 samples):
  python scripts/desk_relight_edits.py --out DIR [--edit NAME] [--views 3,9] [--spp 96]
Each edit lands in DIR/edits/NAME as desk's own edits do (edit.json, transforms.json,
images/, depth/, instances/), so `assist edit --actions DIR/edits/NAME/edit.json` and
`assist eval --data DIR/edits/NAME --split all` measure a scene on it.
"""
import argparse
import os
import sys

DATA = os.environ.get("ASSIST_DATA") or os.path.join(
    os.path.dirname(os.path.abspath(__file__)), "..", "..", "shared", "data")
SCRIPTS = os.path.join(DATA, "desk", "scripts")
if not os.path.exists(os.path.join(SCRIPTS, "render_desk.py")):
    sys.exit(f"desk's render_desk.py not found under {SCRIPTS}: set ASSIST_DATA")
ASSETS = os.path.join(SCRIPTS, "assets")
NEEDED = ["duck.obj", "duckCM.png", "spot_triangulated.obj", "spot_texture.png", "mug.obj",
          "teapot.obj", "lego.obj", "table.png"]
missing = [f for f in NEEDED if not os.path.exists(os.path.join(ASSETS, f))]
if missing:
    sys.exit(f"{ASSETS} lacks {', '.join(missing)}: desk's meshes and textures (its README "
             "names their sources) must be there to render the scene again")
sys.path.insert(0, SCRIPTS)
import render_desk  # noqa: E402  (needs bpy)

EDITS = {
    "rotate_mug": dict(instance_id=3, operation="rotate", config={"degrees": 90.0}),
    "rotate_duck": dict(instance_id=1, operation="rotate", config={"degrees": 180.0}),
    "move_teapot": dict(instance_id=4, operation="translate", config={"offset": [0.56, -0.44, 0.0]}),
}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--edit", choices=sorted(EDITS), action="append")
    ap.add_argument("--views", default=None)
    ap.add_argument("--spp", type=int, default=96)
    a = ap.parse_args()
    render_desk.EDITS.update(EDITS)
    for name in a.edit or sorted(EDITS):
        argv = ["render_desk.py", "--phase", "edit", "--edit", name, "--out", a.out,
                "--spp", str(a.spp), "--skip_existing"]
        if a.views:
            argv += ["--views", a.views]
        sys.argv = argv
        render_desk.main()


if __name__ == "__main__":
    main()
