"""`device=` as a Python user meets it: renders, generated samples and training on a GPU
adapter (lavapipe in CI, where ASSIST_REQUIRE_GPU=1) against the CPU's, and the clear
refusals. Without any adapter the GPU tests skip loudly, unless CI requires one."""

import os
import subprocess
import sys

import numpy as np
import pytest

import assist


def psnr(a, b):
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(1 / mse)


def gpu_or_skip(open_it):
    """`open_it()` on the GPU; a loud skip when there is no adapter and CI does not need one."""
    try:
        return open_it()
    except assist.AssistError as e:
        if "no GPU adapter" in str(e) and os.environ.get("ASSIST_REQUIRE_GPU") != "1":
            pytest.skip("no GPU adapter (install mesa-vulkan-drivers for lavapipe)")
        raise


def test_a_scene_rendered_on_the_gpu_matches_the_cpu(trained):
    cap, scene_path, _ = trained
    on_gpu = gpu_or_skip(lambda: assist.Scene.load(scene_path, device="gpu"))
    on_cpu = assist.Scene.load(scene_path)
    assert on_cpu.device == "cpu" and on_gpu.device not in ("", "cpu")
    cams = [c for c in assist.Dataset.load(cap).cameras if c.split == "test"][:2]
    assert cams
    for cam in cams:
        g = on_gpu.render(cam, outputs=["rgb", "depth", "instance"])
        c = on_cpu.render(cam, outputs=["rgb", "depth", "instance"])
        assert psnr(g["rgb"], c["rgb"]) > 40, cam.name
        assert np.allclose(g["depth"], c["depth"], rtol=1e-3, atol=1e-3), cam.name
        # Ids differ at most where a pixel's opacity sits on the threshold.
        assert np.mean(g["instance"] != c["instance"]) < 0.01, cam.name
    # An edit renders on the GPU as on the CPU (the moved node's field stays resident).
    label = on_cpu.nodes[1]["label"]
    for s in (on_gpu, on_cpu):
        s.apply(f"move the {label} 10 cm left")
    g, c = on_gpu.render(cams[0], outputs=["rgb"]), on_cpu.render(cams[0], outputs=["rgb"])
    assert psnr(g["rgb"], c["rgb"]) > 40


def test_generated_samples_on_the_gpu_match_the_cpu(trained_more):
    _, scene_path, _ = trained_more
    spec = {
        "count": 2,
        "seed": 11,
        "scenes": [{"path": str(scene_path)}],
        "output": {"width": 32, "height": 24},
    }
    on_gpu = gpu_or_skip(lambda: list(assist.generate(spec, device="gpu")))
    on_cpu = list(assist.generate(spec))
    assert [s["actions"] for s in on_gpu] == [s["actions"] for s in on_cpu]
    for g, c in zip(on_gpu, on_cpu):
        for vg, vc in zip(g["views"], c["views"]):
            assert psnr(vg["rgb"], vc["rgb"]) > 40, g["index"]
            assert np.mean(vg["instance"] != vc["instance"]) < 0.01, g["index"]


def test_training_on_the_gpu_matches_the_cpu_and_renders_on_either(trained):
    cap, _, root = trained
    report = gpu_or_skip(
        lambda: assist.train(cap, root / "gpu.assist", iters=12, seed=1, device="gpu")
    )
    cpu = assist.train(cap, root / "cpu.assist", iters=12, seed=1, device="cpu")
    assert report["iterations"] == cpu["iterations"] == 12
    # The training figures of the last step agree, and the GPU's scene renders on the CPU.
    lg, lc = report["final_stats"]["psnr"], cpu["final_stats"]["psnr"]
    assert abs(lg - lc) <= 0.05, (lg, lc)
    cam = [c for c in assist.Dataset.load(cap).cameras if c.split == "test"][0]
    a = assist.Scene.load(root / "gpu.assist").render(cam, outputs=["rgb"])["rgb"]
    b = assist.Scene.load(root / "cpu.assist").render(cam, outputs=["rgb"])["rgb"]
    assert psnr(a, b) > 40


def test_a_device_that_is_not_one_is_refused_by_name(trained, tmp_path):
    cap, scene_path, _ = trained
    for call in (
        lambda: assist.Scene.load(scene_path, device="cuda"),
        lambda: assist.generate({"scenes": [{"path": str(scene_path)}]}, device="cuda"),
        lambda: assist.train(cap, tmp_path / "x.assist", iters=1, device="cuda"),
        lambda: assist.generate_shard(
            {"scenes": [{"path": str(scene_path)}], "count": 1}, tmp_path / "g", device="cuda"
        ),
    ):
        with pytest.raises(assist.AssistError, match='expected auto, cpu or gpu, got "cuda"'):
            call()
    assert not (tmp_path / "x.assist").exists() and not (tmp_path / "g").exists()


def test_without_a_vulkan_driver_gpu_is_refused_and_auto_uses_the_cpu(trained):
    _, scene_path, _ = trained
    # The Vulkan loader finds no driver at all (its variables are read as it starts, so in
    # a fresh interpreter).
    none = "/nonexistent/icd.json"
    env = dict(os.environ, VK_DRIVER_FILES=none, VK_ICD_FILENAMES=none)
    code = f"""
import assist
try:
    assist.Scene.load({str(scene_path)!r}, device="gpu")
    print("opened")
except assist.AssistError as e:
    print("refused:", e)
print("auto:", assist.Scene.load({str(scene_path)!r}, device="auto").device)
"""
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert "refused:" in out.stdout and "no GPU adapter" in out.stdout, out.stdout
    assert 'device="cpu"' in out.stdout and "--device" not in out.stdout, out.stdout
    assert "auto: cpu" in out.stdout, out.stdout
