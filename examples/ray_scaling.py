"""Generation samples/s on a local Ray cluster with 1 and then 2 worker processes (nodes of
1 CPU each, `ray start`), the figure BENCHMARKS.md quotes as the scaling line. Each step
runs `runs` times into fresh folders (the median is printed), then a second node joins.

    python examples/ray_scaling.py SPEC.toml --count 64 --shards 8 --runs 3
"""

import argparse
import json
import os
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import ray

import assist.distributed as ad

RAY = str(Path(sys.executable).with_name("ray"))


def start(args):
    env = dict(os.environ, RAY_USAGE_STATS_ENABLED="0")
    return subprocess.Popen([RAY, "start", "--num-cpus", "1", "--block", *args], env=env,
                            start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def main():
    p = argparse.ArgumentParser()
    p.add_argument("spec")
    p.add_argument("--count", type=int, default=64)
    p.add_argument("--shards", type=int, default=8)
    p.add_argument("--runs", type=int, default=3)
    a = p.parse_args()
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    temp = tempfile.mkdtemp(prefix="ray", dir="/tmp")
    work = Path(tempfile.mkdtemp(prefix="assist-ray-scaling-"))
    address = f"127.0.0.1:{port}"
    procs = [start(["--head", "--port", str(port), "--temp-dir", temp, "--include-dashboard=false"])]
    try:
        for _ in range(60):
            try:
                ray.init(address=address, logging_level="WARNING", log_to_driver=False)
                break
            except Exception:
                time.sleep(1)
        figures = {}
        for workers in (1, 2):
            if workers == 2:
                procs.append(start(["--address", address]))
                while len([n for n in ray.nodes() if n["Alive"]]) < 2:
                    time.sleep(0.5)
            rates = []
            for r in range(a.runs):
                out = work / f"w{workers}-r{r}"
                res = ad.generate(a.spec, count=a.count, out=out, shards=a.shards, address=address, progress=False)
                rates.append(res["samples"] / res["seconds"])
                shutil.rmtree(out)
            figures[workers] = {"samples_per_second": rates, "median": statistics.median(rates)}
            print(f"{workers} worker process(es): {statistics.median(rates):.2f} samples/s "
                  f"(runs: {', '.join(f'{x:.2f}' for x in rates)})", flush=True)
        figures["speedup"] = figures[2]["median"] / figures[1]["median"]
        print(json.dumps(figures))
    finally:
        ray.shutdown()
        for pr in reversed(procs):
            os.killpg(pr.pid, signal.SIGTERM)
            pr.wait()
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
