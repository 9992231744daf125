"""The Python API as a user meets it, checked against the CLI it shares its code with."""

import json

import numpy as np
import pytest
from PIL import Image

import assist
from conftest import run


def to8(rgb):
    """What our PNG writer stores: `(clamp(v, 0, 1) * 255).round()` in float32, halves away
    from zero (numpy's `round` takes halves to even, which differs on exact halves)."""
    y = np.clip(rgb, 0, 1).astype(np.float32) * np.float32(255)
    f = np.floor(y)
    return np.where(y - f >= np.float32(0.5), f + 1, f).astype(np.uint8)


def test_render_equals_assist_render_bit_for_bit(trained):
    cap, scene_path, root = trained
    out = root / "cli-render"
    run("render", scene_path, "--cameras", cap, "--split", "test", "--outputs", "rgb,depth,panoptic", "--out", out)
    scene = assist.Scene.load(scene_path)
    cams = [c for c in assist.Dataset.load(cap).cameras if c.split == "test"]
    assert cams, "the capture has test views"
    for cam in cams:
        r = scene.render(cam)
        assert r["rgb"].dtype == np.float32 and r["rgb"].shape == (cam.height, cam.width, 3)
        png = np.array(Image.open(out / "images" / f"{cam.name}.png").convert("RGB"))
        mine = to8(r["rgb"])
        assert np.array_equal(mine, png), cam.name
        depth = np.load(out / "depth" / f"{cam.name}.npy")
        assert np.array_equal(r["depth"], depth * np.float32(scene.meters_per_unit)), cam.name
        ids = np.array(Image.open(out / "panoptic" / f"{cam.name}.png"))
        assert np.array_equal(r["instance"], ids.astype(np.uint16)), cam.name


def test_apply_text_equals_edit_dry_run(trained):
    _, scene_path, _ = trained
    scene = assist.Scene.load(scene_path)
    label = scene.nodes[1]["label"]
    text = f"move the {label} 10 cm left and rotate it 30 degrees"
    cli = json.loads(run("edit", scene_path, "--do", text, "--dry-run", "--json").stdout)
    assert scene.plan(text) == cli
    assert scene.apply(text) == cli
    before = scene.nodes[1]["pose"].copy()
    assert scene.undo()
    assert not np.array_equal(scene.nodes[1]["pose"], before)
    assert scene.redo()
    assert np.array_equal(scene.nodes[1]["pose"], before)


def test_actions_undo_and_save(trained):
    _, scene_path, root = trained
    scene = assist.Scene.load(scene_path)
    ids = [n["id"] for n in scene.nodes if not n["background"]]
    done = scene.apply([{"instance_id": ids[0], "operation": "delete", "config": {}}])
    assert done == [{"instance_id": ids[0], "operation": "delete", "config": {}}]
    assert ids[0] not in [n["id"] for n in scene.nodes]
    out = root / "saved.assist"
    scene.save(out)
    again = assist.Scene.load(out)
    assert [n["id"] for n in again.nodes] == [n["id"] for n in scene.nodes]
    with pytest.raises(assist.AssistError, match="--force|exists|not empty"):
        scene.save(out)
    scene.save(out, force=True)


def test_pick_names_the_object_under_a_pixel(trained):
    cap, scene_path, _ = trained
    scene = assist.Scene.load(scene_path)
    cam = assist.Dataset.load(cap).cameras[0]
    r = scene.render(cam, outputs=["instance"])
    ys, xs = np.nonzero(r["instance"])
    if len(xs) == 0:
        pytest.skip("no object in view")
    y, x = int(ys[len(ys) // 2]), int(xs[len(xs) // 2])
    assert scene.pick(cam, x + 0.5, y + 0.5) == int(r["instance"][y, x])


def test_cameras_from_numpy_and_orbit(trained):
    cap, scene_path, _ = trained
    scene = assist.Scene.load(scene_path)
    ds_cam = assist.Dataset.load(cap).cameras[0]
    fx, fy, cx, cy = ds_cam.intrinsics
    mine = assist.Camera(ds_cam.pose, fx, fy, cx, cy, ds_cam.width, ds_cam.height)
    a = scene.render(mine, outputs=["rgb"])["rgb"]
    b = scene.render(ds_cam, outputs=["rgb"])["rgb"]
    assert np.array_equal(a, b)
    small = scene.render(mine, outputs=["rgb", "opacity", "unseen"], width=24)
    assert small["rgb"].shape == (18, 24, 3) and small["opacity"].shape == (18, 24)
    # What no ray met has no opacity.
    assert small["unseen"].dtype == np.bool_ and small["unseen"].shape == (18, 24)
    assert np.all(small["opacity"][small["unseen"]] == 0)
    orbit = assist.orbit(scene, frames=3, width=32, height=24)
    assert len(orbit) == 3 and orbit[0].width == 32


def test_bad_input_raises_with_the_library_message(trained, tmp_path):
    _, scene_path, _ = trained
    with pytest.raises(assist.AssistError, match="nowhere.assist"):
        assist.Scene.load(tmp_path / "nowhere.assist")
    scene = assist.Scene.load(scene_path)
    with pytest.raises(assist.AssistError, match="giraffe"):
        scene.apply("delete the giraffe")
    with pytest.raises(assist.AssistError, match="instance_id 999"):
        scene.apply([{"instance_id": 999, "operation": "delete", "config": {}}])
    with pytest.raises(assist.AssistError, match="unknown field"):
        scene.apply([{"instance_id": 1, "operation": "delete", "config": {"colour": 1}}])
    pose = np.eye(4)
    pose[0, 3] = np.nan
    with pytest.raises(assist.AssistError, match="pose"):
        assist.Camera(pose, 50.0, 50.0, 24.0, 18.0, 48, 36)
    with pytest.raises(assist.AssistError, match="outputs"):
        scene.render(assist.orbit(scene, frames=1)[0], outputs=["normals"])
    with pytest.raises(assist.AssistError, match="split"):
        assist.cameras(tmp_path, split="sideways")


def test_the_quickstart_example_runs(trained):
    import subprocess
    import sys
    from pathlib import Path

    cap, scene_path, root = trained
    example = Path(__file__).resolve().parents[3] / "examples" / "python_quickstart.py"
    out = subprocess.run(
        [sys.executable, str(example), str(scene_path), str(cap), str(root / "qs")],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stderr
    assert "AssistError:" in out.stdout and "batch (4," in out.stdout
    assert (root / "qs" / "edited.assist" / "scene.json").is_file()


def test_generate_yields_the_samples_assist_generate_writes(trained_more):
    cap, scene_path, root = trained_more
    spec = {
        "count": 4,
        "seed": 11,
        "scenes": [{"path": str(scene_path)}],
        "output": {"width": 32, "height": 24},
    }
    batches = []
    samples = assist.generate(spec)
    assert len(samples) == 4
    for s in samples:
        v = s["views"][0]
        assert v["rgb"].shape == (24, 32, 3) and v["rgb"].dtype == np.float32
        assert v["instance"].dtype == np.uint16 and v["semantic"].dtype == np.uint16
        assert v["unobserved"].dtype == np.bool_
        assert {a["operation"] for a in s["actions"]} <= {"delete", "rotate", "scale", "translate", "add"}
        batches.append(v["rgb"])
    batch = np.stack(batches)
    assert batch.shape == (4, 24, 32, 3)
    # The same indices on disk, by the CLI.
    toml = root / "gen.toml"
    toml.write_text(
        f'count = 4\nseed = 11\n[[scenes]]\npath = "{scene_path}"\n[output]\nwidth = 32\nheight = 24\n'
    )
    out = root / "gen"
    run("generate", "--spec", toml, "--out", out)
    for i, rgb in enumerate(batches):
        png = np.array(Image.open(out / "samples" / f"{i:06d}" / "views" / "images" / "v0.png").convert("RGB"))
        assert np.array_equal(to8(rgb), png), i
    # A later start, and spec errors as exceptions.
    assert next(iter(assist.generate(spec, start=3)))["index"] == 3
    with pytest.raises(assist.AssistError, match="unknown field"):
        assist.generate({"scenes": [{"path": str(scene_path)}], "colour": 1})
    # A value of the wrong kind is named by where it stands in the spec.
    with pytest.raises(assist.AssistError, match=r"spec: scenes\[0\]\.path: invalid type"):
        assist.generate({"scenes": [{"path": 7}]})
    with pytest.raises(assist.AssistError, match="count"):
        assist.generate(spec, count=0)


def test_train_reports_and_calls_back(trained):
    cap, _, root = trained
    events = []
    report = assist.train(cap, root / "py.assist", iters=4, callback=events.append, checkpoint_every=1e9)
    assert report["iterations"] == 4 and report["stopped_by"] == "iterations"
    kinds = [e["event"] for e in events]
    assert "loading" in kinds and kinds.count("step") == 4 and kinds[-1] == "saved"
    assert assist.Scene.load(root / "py.assist").nodes
    # A callback that raises stops the run and its exception comes back.
    def stop(e):
        if e["event"] == "step":
            raise RuntimeError("enough")
    with pytest.raises(RuntimeError, match="enough"):
        assist.train(cap, root / "py2.assist", iters=50, callback=stop)
    # Keywords are the CLI's long flags with `_`, recorded in the trained scene.
    assist.train(cap, root / "py5.assist", iters=2, lambda_obj_share=0.0, shadows="off",
                 reflect="on", lambda_normal=0.01)
    record = json.loads((root / "py5.assist" / "scene.json").read_text())["info"]["train_config"]
    assert record["lambda_obj_share"] == 0.0 and record["shadows"] == "off"
    assert record["reflect"] == "on" and record["lambda_normal"] == pytest.approx(0.01)
    with pytest.raises(assist.AssistError, match="reflect"):
        assist.train(cap, root / "py6.assist", iters=1, reflect="sometimes")
    with pytest.raises(assist.AssistError, match='unknown option "colour"'):
        assist.train(cap, root / "py3.assist", colour=1)
    with pytest.raises(assist.AssistError, match="nowhere"):
        assist.train(root / "nowhere", root / "py4.assist", iters=1)


def test_add_from_another_scene(trained):
    _, scene_path, _ = trained
    scene = assist.Scene.load(scene_path)
    other = assist.Scene.load(scene_path)
    src = next(n for n in other.nodes if not n["background"])
    before = {n["id"] for n in scene.nodes}
    done = scene.add_from(scene_path, src["label"], position=[0.0, 0.0, 0.8])
    assert done[0]["operation"] == "add"
    new = {n["id"] for n in scene.nodes} - before
    assert len(new) == 1
    node = next(n for n in scene.nodes if n["id"] in new)
    # its label is taken in this scene: it is numbered as a copy is
    assert node["label"] == f'{src["label"]} 2'
    assert node["class"] == src["class"] == src["label"]
    assert np.allclose(node["pose"][:3, 3], [0.0, 0.0, 0.8])
    with pytest.raises(assist.AssistError, match="giraffe"):
        scene.add_from(scene_path, "giraffe")


def test_ctrl_c_saves_the_scene_and_raises_keyboard_interrupt(trained):
    import signal
    import subprocess
    import sys
    import time

    cap, _, root = trained
    out = root / "interrupted.assist"
    # Python installs its Ctrl+C handler only when SIGINT is not ignored at start, and a
    # test run launched in the background (`cmd &` in a script) inherits it ignored: set
    # the handler an interactive user has.
    code = (
        "import assist, signal, sys\n"
        "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
        "def cb(e):\n"
        "    if e['event'] == 'step' and e['stats']['iteration'] == 1:\n"
        "        print('training', flush=True)\n"
        f"assist.train({str(cap)!r}, {str(out)!r}, iters=100000, callback=cb, checkpoint_every=1e9)\n"
    )
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert p.stdout.readline().strip() == "training"
        time.sleep(1.0)
        p.send_signal(signal.SIGINT)
        _, err = p.communicate(timeout=120)
    finally:
        # Never leave a training run behind (it would slow every test after it).
        if p.poll() is None:
            p.kill()
            p.wait()
    assert p.returncode != 0
    assert "KeyboardInterrupt" in err, err
    assert (out / "scene.json").is_file(), "the interrupted run saved the scene"
    info = __import__("json").loads((out / "scene.json").read_text())["info"]
    assert 1 <= info["iteration"] < 100000


def test_select_highlights_and_checks_the_id(trained):
    cap, scene_path, _ = trained
    scene = assist.Scene.load(scene_path)
    cam = assist.Dataset.load(cap).cameras[0]
    plain = scene.render(cam, outputs=["rgb", "instance"])
    seen = sorted(set(np.unique(plain["instance"]).tolist()) - {0})
    if not seen:
        pytest.skip("no object in view")
    scene.select(seen[0])
    lit = scene.render(cam, outputs=["rgb"])["rgb"]
    mask = plain["instance"] == seen[0]
    assert not np.array_equal(lit[mask], plain["rgb"][mask]), "the selection is highlighted"
    scene.select(None)
    assert np.array_equal(scene.render(cam, outputs=["rgb"])["rgb"], plain["rgb"])
    with pytest.raises(assist.AssistError, match="no node with id 999"):
        scene.select(999)


def test_export_equals_assist_export(trained_more, tmp_path):
    _, scene_path, _ = trained_more[:3]
    scene = assist.Scene.load(scene_path)
    # The same folder name (the MJCF model is named after it), in two places.
    py, cli = tmp_path / "py" / "meshes", tmp_path / "cli" / "meshes"
    done = scene.export(py, resolution=48, sim="mjcf")
    run("export", scene_path, "--out", cli, "--resolution", "48", "--sim", "mjcf")
    assert done["model"] == "scene.xml"
    assert len(done["nodes"]) == sum(1 for n in scene.nodes if not n["background"])
    for n in done["nodes"]:
        assert n["closed"] and n["triangles"] > 0, n
        assert (py / n["file"]).read_bytes() == (cli / n["file"]).read_bytes()
    assert (py / "scene.xml").read_bytes() == (cli / "scene.xml").read_bytes()
    with pytest.raises(assist.AssistError, match="giraffe"):
        scene.export(tmp_path / "bad", nodes=["giraffe"])
    with pytest.raises(assist.AssistError, match="format"):
        scene.export(tmp_path / "bad", format="stl")
    with pytest.raises(assist.AssistError, match="force"):
        scene.export(py)


def test_rename_is_one_undo_step_and_keeps_the_class(trained):
    _, scene_path, _ = trained
    scene = assist.Scene.load(scene_path)
    a, b = [n for n in scene.nodes if not n["background"]][:2]
    scene.rename(a["id"], "my favourite thing")
    renamed = next(n for n in scene.nodes if n["id"] == a["id"])
    assert renamed["label"] == "my favourite thing"
    assert renamed["class"] == a["class"]
    with pytest.raises(assist.AssistError, match="already called"):
        scene.rename(b["id"], "My Favourite Thing")
    assert scene.undo()
    assert next(n for n in scene.nodes if n["id"] == a["id"])["label"] == a["label"]


def test_set_scale_from_an_objects_height_is_one_undo_step(trained):
    _, scene_path, _ = trained
    scene = assist.Scene.load(scene_path)
    assert scene.meters_per_unit == 1.0
    a = next(n for n in scene.nodes if not n["background"])
    mpu = scene.set_scale(str(a["id"]), height_m=0.12)
    assert mpu > 0 and scene.meters_per_unit == pytest.approx(mpu)
    assert scene.undo()
    assert scene.meters_per_unit == 1.0
    assert scene.set_scale(meters_per_unit=0.5) == 0.5
    with pytest.raises(assist.AssistError, match="height_m"):
        scene.set_scale(str(a["id"]), height_m=-1.0)
    with pytest.raises(assist.AssistError, match="meters_per_unit"):
        scene.set_scale(meters_per_unit=0.0)
    with pytest.raises(assist.AssistError, match="give node"):
        scene.set_scale(str(a["id"]))


def test_bad_numbers_raise_assist_error_naming_the_argument(trained):
    """Issue 47 items 17 and 18: negative sizes and ids raised OverflowError, and a NaN in
    a dict said "expected value at line 1 column 68"."""
    _, scene_path, _ = trained
    scene = assist.Scene.load(scene_path)
    cam = assist.orbit(scene, frames=1)[0]
    for call, name in [
        (lambda: scene.render(cam, width=-1), "width"),
        (lambda: scene.render(cam, width=0), "width: expected 1 to 16384 pixels, got 0"),
        (lambda: scene.render(cam, height=10**30), "height"),
        (lambda: assist.orbit(scene, frames=-3), "frames"),
        (lambda: scene.select(-1), "id"),
        (lambda: scene.rename(70000, "mug"), "id"),
        (lambda: assist.Camera(np.eye(4), 50.0, 50.0, 24.0, 18.0, -48, 36), "width"),
    ]:
        with pytest.raises(assist.AssistError, match=name):
            call()
    with pytest.raises(TypeError, match="width"):
        scene.render(cam, width="wide")
    nan = [{"instance_id": 1, "operation": "translate", "config": {"vector": [float("nan"), 0, 0]}}]
    with pytest.raises(assist.AssistError, match=r"actions\[0\]\.config\.vector\[0\]"):
        scene.apply(nan)
    # numpy values read as the numbers they hold.
    moved = scene.plan([{"instance_id": np.int64(1), "operation": "translate",
                         "config": {"vector": np.array([0.01, 0.0, 0.0]), "unit": "m"}}])
    assert moved[0]["instance_id"] == 1


def test_threads_share_a_scene(trained):
    """Issue 47 item 18: editing a Scene while another thread rendered it raised
    RuntimeError('Already borrowed'); now the edit waits for the render."""
    import threading

    _, scene_path, _ = trained
    scene = assist.Scene.load(scene_path)
    cam = assist.orbit(scene, frames=1)[0]
    errors = []

    def render():
        try:
            for _ in range(3):
                scene.render(cam, width=64)
        except Exception as e:  # noqa: BLE001 - the test reports whatever went wrong
            errors.append(e)

    t = threading.Thread(target=render)
    t.start()
    for _ in range(5):
        scene.apply("move object 1 1 cm left")
        scene.undo()
    t.join()
    assert not errors, errors


def test_ctrl_c_stops_render_and_plan(trained):
    """Issue 47 item 18: Scene.render and Scene.plan ran on for a minute after SIGINT."""
    import signal
    import subprocess
    import sys
    import time

    _, scene_path, _ = trained
    code = (
        "import assist, signal, time\n"
        "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
        f"scene = assist.Scene.load({str(scene_path)!r})\n"
        "cam = assist.orbit(scene, frames=1)[0]\n"
        "print('rendering', flush=True)\n"
        "t = time.time()\n"
        "try:\n"
        "    scene.render(cam, width=4096)\n"
        "except KeyboardInterrupt:\n"
        "    print('interrupted after', time.time() - t, flush=True)\n"
        "    scene.apply('move object 1 1 cm left')\n"
        "    print('usable', flush=True)\n"
    )
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert p.stdout.readline().strip() == "rendering"
        time.sleep(1.5)
        sent = time.time()
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=60)
        waited = time.time() - sent
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    assert "interrupted after" in out, (out, err)
    assert "usable" in out, (out, err)
    # The render stops at its next batch of rays: seconds, not the minute a 4096-wide
    # frame takes on two cores.
    assert waited < 20, waited


def test_process_checks_its_arguments_and_calls_back(trained, tmp_path):
    """`assist.process` as `assist process`: arguments checked by name; a folder with one
    photograph refused with nothing written, after the callback saw the first stage."""
    import shutil

    cap, _, _ = trained
    with pytest.raises(assist.AssistError, match="matcher"):
        assist.process(cap / "images", tmp_path / "d", matcher="nearest")
    with pytest.raises(assist.AssistError, match="cameras"):
        assist.process(cap / "images", tmp_path / "d", cameras="per-image")
    with pytest.raises(assist.AssistError, match="scale_by"):
        assist.process(cap / "images", tmp_path / "d", scale_by="3:1,2 4:5,6 1ft")
    with pytest.raises(assist.AssistError, match="frames"):
        assist.process(cap / "images", tmp_path / "d", frames=-1)
    if shutil.which("colmap") is None:
        pytest.skip("colmap is not installed (Debian's colmap package)")
    one = tmp_path / "one"
    one.mkdir()
    first = sorted((cap / "images").iterdir())[0]
    shutil.copy(first, one / first.name)
    events = []
    with pytest.raises(assist.AssistError, match="at least 3"):
        assist.process(one, tmp_path / "d", callback=events.append)
    assert events and events[0]["kind"] == "stage" and events[0]["stage"] == "frames"
    assert not (tmp_path / "d").exists()


def test_split_makes_an_object_node_of_a_scene_trained_without_masks(trained, tmp_path):
    """`assist.split` as `assist scene split`: a box makes an object node with its field
    from the background's and a short fine-tune, as one undo step; the callback sees the
    masks and the field's start; a bad box is refused by name with nothing written."""
    cap, _, _ = trained
    plain = tmp_path / "plain.assist"
    assist.train(cap, plain, iters=60, no_objects=True)
    assert len(assist.Scene.load(plain).nodes) == 1
    inst = json.loads((cap / "transforms.json").read_text())["instances"][0]["bbox"]
    box = ",".join(str(v) for v in inst["center"] + [s * 1.3 for s in inst["size"]])
    events = []
    out = tmp_path / "split.assist"
    made = assist.split(plain, out, boxes=[box], labels=["thing"], iters=5, callback=events.append)
    assert [(o["id"], o["label"]) for o in made["objects"]] == [(1, "thing")]
    kinds = {e["kind"] for e in events}
    assert {"masks", "distilled", "step"} <= kinds, kinds
    s = assist.Scene.load(out)
    assert [n["label"] for n in s.nodes] == ["background", "thing"]
    assert s.undo() and len(s.nodes) == 1
    with pytest.raises(assist.AssistError, match="box"):
        assist.split(plain, tmp_path / "bad.assist", boxes=["1,2"])
    assert not (tmp_path / "bad.assist").exists()
