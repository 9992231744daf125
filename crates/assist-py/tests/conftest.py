"""Fixtures: a small trained scene made with the `assist` binary (ASSIST_BIN)."""

import os
import shutil
import subprocess
from pathlib import Path

import pytest


def assist_bin():
    b = os.environ.get("ASSIST_BIN")
    if not b:
        pytest.skip("ASSIST_BIN (the assist binary) is not set")
    return b


def run(*args):
    out = subprocess.run([assist_bin(), *map(str, args)], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    return out


@pytest.fixture(scope="session")
def trained(tmp_path_factory):
    """A synthetic capture (12 views of 48×36, 3 objects) and a scene trained on it."""
    root = tmp_path_factory.mktemp("assist")
    cap = root / "cap"
    run("synth", "--out", cap, "--views", "12", "--width", "48", "--height", "36", "--objects", "3")
    scene = root / "s.assist"
    run("train", cap, "--out", scene, "--iters", "30")
    return cap, scene, root


@pytest.fixture(scope="session")
def trained_more(tmp_path_factory):
    """A capture with a table to stand on (30 views of 96×72, 4 objects) and a scene
    trained enough for the generator to find it (400 steps). The Rust test that runs this
    suite hands over the one its CLI tests trained (ASSIST_TEST_GENERATOR_SCENE: a folder
    with `cap` and `s.assist`, made the same way); it is copied, not trained again."""
    root = tmp_path_factory.mktemp("assist-gen")
    cap = root / "cap"
    scene = root / "s.assist"
    given = os.environ.get("ASSIST_TEST_GENERATOR_SCENE")
    if given:
        shutil.copytree(Path(given) / "cap", cap)
        shutil.copytree(Path(given) / "s.assist", scene)
        return cap, scene, root
    run("synth", "--out", cap, "--views", "30", "--width", "96", "--height", "72", "--objects", "4")
    run("train", cap, "--out", scene, "--iters", "400")
    return cap, scene, root
