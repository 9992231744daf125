"""`assist.distributed` on a real local Ray cluster: a head node and a second worker node,
each its own `ray start` process with 1 CPU. Generation across both equals one process's
run file for file, also when the worker node is killed while a shard runs on it. Two
scenes are trained as tasks. Ray missing, an unreachable address and an output folder the
driver cannot see are refused with what to do. Skipped when Ray is not installed, unless
ASSIST_REQUIRE_RAY is set (CI sets it)."""

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pytest

import assist
from conftest import run

if os.environ.get("ASSIST_REQUIRE_RAY"):
    import ray  # noqa: F401 (CI: Ray must be there)
else:
    ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'assist[ray]')")

RAY = str(Path(sys.executable).with_name("ray"))


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start(args):
    """A `ray start … --block` in its own process group: the node's raylet and workers
    are its children, so killing the group kills the node."""
    env = dict(os.environ, RAY_USAGE_STATS_ENABLED="0")
    return subprocess.Popen(
        [RAY, "start", "--num-cpus", "1", "--block", *args],
        env=env,
        start_new_session=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


def alive_nodes():
    return [n for n in ray.nodes() if n["Alive"]]


@pytest.fixture(scope="module")
def cluster():
    port = free_port()
    # Short: Ray's unix sockets live under it (paths are limited to 107 bytes).
    temp = tempfile.mkdtemp(prefix="ray", dir="/tmp")
    head = start(["--head", "--port", str(port), "--temp-dir", temp, "--include-dashboard=false"])
    address = f"127.0.0.1:{port}"
    worker = None
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                ray.init(address=address, logging_level="WARNING", log_to_driver=False)
                break
            except Exception:
                if time.monotonic() > deadline:
                    raise
                time.sleep(1)
        worker = start(["--address", address])
        while len(alive_nodes()) < 2:
            assert time.monotonic() < deadline + 60, "the worker node did not join"
            time.sleep(0.5)
        yield {"address": address, "worker": worker}
    finally:
        ray.shutdown()
        # Both nodes told at once; a `ray start --block` can take half a minute over
        # SIGTERM, which this throwaway cluster need not wait for.
        nodes = [p for p in (worker, head) if p is not None and p.poll() is None]
        for p in nodes:
            os.killpg(p.pid, signal.SIGTERM)
        deadline = time.monotonic() + 5
        for p in nodes:
            try:
                p.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
        shutil.rmtree(temp, ignore_errors=True)


def tree(d):
    """Every file under `d` but the shards' completion records (relative path → bytes)."""
    d = Path(d)
    return {
        str(p.relative_to(d)): p.read_bytes()
        for p in sorted(d.rglob("*"))
        if p.is_file() and p.relative_to(d).parts[0] != "shards"
    }


def spec_file(root, scene, count):
    p = root / f"spec{count}.toml"
    p.write_text(
        f"""count = {count}
seed = 3

[[scenes]]
path = "{scene}"

[objects]
keep = 0.8
move = 0.8

[output]
width = 64
height = 48
"""
    )
    return p


def processes():
    """(pid, parent pid, process group, command line) of every process."""
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
            yield int(d.name), int(fields[1]), int(fields[2]), (d / "cmdline").read_bytes()
        except (OSError, ValueError, IndexError):
            continue


def shard_tasks_of_node(pgid):
    """The processes of the node `ray start` started in group `pgid` that are running a
    shard: children of its raylet titled `ray::_shard_task` (Ray titles a worker busy with
    a task `ray::NAME`; newer Rays start each worker in a process group of its own)."""
    procs = list(processes())
    raylets = {p for p, _, g, cmd in procs if g == pgid and b"raylet/raylet" in cmd}
    return [p for p, pp, _, cmd in procs if pp in raylets and cmd.startswith(b"ray::_shard_task")]


def kill_node(pgid):
    """Kills a node as a machine dies: its shard workers, its raylet and the rest."""
    for p in shard_tasks_of_node(pgid):
        try:
            os.kill(p, signal.SIGKILL)
        except ProcessLookupError:
            pass
    os.killpg(pgid, signal.SIGKILL)


def test_generate_on_two_nodes_equals_one_process_even_when_a_node_dies(cluster, trained_more):
    cap, scene, root = trained_more
    sp = spec_file(root, scene, 48)
    whole = root / "whole"
    run("generate", "--spec", sp, "--out", whole)
    want = tree(whole)

    # 8 shards over both nodes.
    out = root / "ray8"
    r = assist.distributed.generate(sp, out=out, shards=8, address=cluster["address"], progress=False)
    assert r["shards"] == 8 and r["samples"] == 48 and r["made"] == 48, r
    nodes = {s["node_id"] for s in r["per_shard"]}
    assert len(nodes) == 2, f"the shards ran on {len(nodes)} node(s), not both"
    assert tree(out) == want, "8 Ray shards differ from one process's run"
    st = assist.status(out)
    assert st["all_complete"] and st["shards"] == 8, st

    # The worker node killed while a shard runs on it: Ray retries the shard on the head.
    out2 = root / "ray8-killed"
    result, failure = {}, []

    def drive():
        try:
            result.update(
                assist.distributed.generate(sp, out=out2, shards=8, address=cluster["address"], progress=False)
            )
        except Exception as e:  # reported below
            failure.append(e)

    t = threading.Thread(target=drive)
    t.start()
    worker = cluster["worker"]
    deadline = time.monotonic() + 120
    while not shard_tasks_of_node(worker.pid):
        assert time.monotonic() < deadline and t.is_alive(), f"no shard ran on the worker node ({nodes})"
        time.sleep(0.05)
    kill_node(worker.pid)
    worker.wait()
    t.join(timeout=300)
    assert not t.is_alive(), "the run did not finish after the worker node died"
    assert not failure, failure
    assert result["samples"] == 48, result
    assert tree(out2) == want, "the run with a killed node differs from one process's run"


def test_train_two_scenes_as_tasks(cluster, tmp_path):
    caps = []
    for k in range(2):
        c = tmp_path / f"cap{k}"
        run("synth", "--out", c, "--views", "8", "--width", "32", "--height", "24", "--objects", "3", "--seed", str(k))
        caps.append(c)
    out = tmp_path / "scenes"
    reports = assist.distributed.train(caps, out, address=cluster["address"], iters=20, progress=False)
    assert [Path(r["scene"]).name for r in reports] == ["cap0.assist", "cap1.assist"], reports
    for r in reports:
        s = assist.Scene.load(r["scene"])
        assert len(s.nodes) == 4, s.nodes  # the background and three objects
        assert Path(r["log"]).read_text().count('"event"') >= 2
    # Again: both are done, nothing is trained.
    again = assist.distributed.train(caps, out, address=cluster["address"], iters=20, progress=False)
    assert all(r.get("skipped") for r in again), again


def test_errors_say_what_to_do(tmp_path):
    # Ray missing: the extra to install is named.
    code = "import sys; sys.modules['ray'] = None\nimport assist\ntry:\n    assist.distributed.generate('x', out='y')\nexcept ImportError as e:\n    print(e)"
    o = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert "pip install 'assist[ray]'" in o.stdout, o.stdout + o.stderr
    # An address where no cluster answers: refused at once, not after Ray's minutes of
    # retries (in a fresh process: this one is connected to the test cluster).
    code = (
        "import assist, time\nt = time.monotonic()\ntry:\n"
        f"    assist.distributed.generate('x', out='y', address='127.0.0.1:{free_port()}')\n"
        "except assist.AssistError as e:\n    print(e, time.monotonic() - t)"
    )
    o = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert "cannot reach the Ray cluster" in o.stdout and "ray start --head" in o.stdout, o.stdout + o.stderr
    # A shard whose output the driver cannot see: the folder is not shared.
    with pytest.raises(assist.AssistError, match="not visible here.*share"):
        assist.distributed._check_visible(
            {"shard": "3/8", "node": "node-b", "record": str(tmp_path / "elsewhere/shards/3-of-8.json")},
            tmp_path,
        )
