"""Generation shards and trainings as tasks on a Ray cluster (`pip install 'assist[ray]'`).

assist does not schedule; Ray does. `generate` runs one Ray task per shard. Each task
writes its samples into the shared output folder through the code behind `assist generate
--shard i/n`, so a retried task remakes only what does not hold and a complete shard does
nothing. When every shard's completion record is in place, the driver merges. `train` runs
one task per dataset. Each has its own log and checkpoints into its scene, and a retry
resumes from the last checkpoint.

The output folder must be on a filesystem that every node and the driver see at the same
path: NFS, a cluster filesystem, or a one-machine cluster's own disk. On node-local disks
each node's samples stay on that node. The driver detects a shard that reports done but
whose completion record it cannot see, and says so.
"""

import os
import socket
import sys
import time
from pathlib import Path

from ._assist import AssistError, generate_shard, merge, status
from ._assist import train as _train


def _ray():
    try:
        import ray
    except ImportError:
        raise ImportError(
            "assist.distributed needs Ray, which is not installed: pip install 'assist[ray]' "
            "(or pip install ray)"
        ) from None
    return ray


def _reachable(address, timeout=5.0):
    """Whether a `host:port` (or `ray://host:port`) address accepts connections: Ray's
    own connect retries for minutes before it gives up."""
    a = address.split("://", 1)[-1]
    host, sep, port = a.rpartition(":")
    if not sep or not port.isdigit():
        return True  # "auto", "local", or a form Ray resolves itself.
    try:
        with socket.create_connection((host or "127.0.0.1", int(port)), timeout=timeout):
            return True
    except OSError:
        return False


def _connect(ray, address):
    if ray.is_initialized():
        return
    if address and not _reachable(address):
        raise AssistError(
            f"cannot reach the Ray cluster at {address!r}: nothing answers there. Start one "
            "with `ray start --head`, pass its address (`ray status` prints it), or "
            "address=None for a cluster on this machine"
        )
    try:
        ray.init(address=address, logging_level="WARNING", log_to_driver=False)
    except Exception as e:  # Ray raises ConnectionError, RuntimeError, …
        raise AssistError(f"cannot connect to the Ray cluster at {address!r}: {e}") from e


def _where():
    return f"{socket.gethostname()} (pid {os.getpid()})"


def _shard_task(spec, out, shard, seed, count, coco_masks, device):
    import ray

    r = generate_shard(
        spec, out, shard=shard, seed=seed, count=count, coco_masks=coco_masks, device=device
    )
    r["node"] = _where()
    r["node_id"] = ray.get_runtime_context().get_node_id()
    return r


def _progress(done, total, t0, what):
    """A bar over the tasks on a terminal, a line per finished task otherwise."""
    el = time.monotonic() - t0
    eta = el / done * (total - done) if done else float("nan")
    text = f"{done}/{total} {what}, {el:.0f} s, ETA {eta:.0f} s"
    if sys.stderr.isatty():
        filled = round(30 * done / max(total, 1))
        end = "\n" if done == total else ""
        print(f"\r[{'#' * filled}{'.' * (30 - filled)}] {text}", end=end, file=sys.stderr, flush=True)
    else:
        print(text, file=sys.stderr, flush=True)


def _check_visible(result, out):
    """A shard reported done: its completion record must be visible here, or the output
    folder is not shared between the nodes and the driver."""
    record = Path(result["record"])
    if not record.is_file():
        raise AssistError(
            f"shard {result['shard']} finished on {result.get('node', 'a worker')} but its "
            f"completion record {record} is not visible here: the output folder {out} must be "
            "on a filesystem every node and this driver share at the same path (NFS, a "
            "cluster filesystem); on node-local disks each node keeps its own samples"
        )


def generate(
    spec,
    count=None,
    out=None,
    shards=None,
    address=None,
    seed=None,
    max_retries=3,
    cpus_per_shard=1,
    coco_masks="polygon",
    progress=True,
    device="cpu",
):
    """Makes the run `spec` describes (a TOML/JSON path or a dict; `count` and `seed`
    override its own) into the folder `out`, as `shards` Ray tasks, then merges. Default
    `shards`: the cluster's CPUs over `cpus_per_shard`, at most `count`. A task lost with
    its node is retried up to `max_retries` times; a retry remakes only the samples that do
    not hold. The merged result is the same, file for file, as `assist generate` of the
    same spec in one process (the completion records in `out/shards/` aside). Returns a
    summary: shards, samples, seconds, samples_per_second, the merge's and each shard's.
    `device` is where each task queries the fields ("cpu", "gpu" or "auto", on its node).
    """
    if out is None:
        raise AssistError("out: expected the output folder (shared by every node)")
    ray = _ray()
    _connect(ray, address)
    if isinstance(spec, (str, os.PathLike)):
        spec = str(Path(spec).resolve())
    out = str(Path(out).resolve())
    if count is None and isinstance(spec, dict):
        count = spec.get("count")
    n = shards
    if n is None:
        cpus = int(ray.cluster_resources().get("CPU", 1))
        n = max(1, cpus // max(1, int(cpus_per_shard)))
        if count is not None:
            n = min(n, int(count))
    n = int(n)
    if n < 1:
        raise AssistError(f"shards: expected at least 1, got {n}")
    threads = str(max(1, int(cpus_per_shard)))
    task = ray.remote(_shard_task).options(
        num_cpus=cpus_per_shard,
        max_retries=max_retries,
        retry_exceptions=False,
        scheduling_strategy="SPREAD",
        runtime_env={"env_vars": {"RAYON_NUM_THREADS": threads}},
    )
    t0 = time.monotonic()
    pending = {
        task.remote(spec, out, f"{i}/{n}", seed, count, coco_masks, device): i for i in range(n)
    }
    results = {}
    while pending:
        ready, _ = ray.wait(list(pending), num_returns=1)
        for ref in ready:
            i = pending.pop(ref)
            try:
                r = ray.get(ref)
            except ray.exceptions.RayTaskError as e:
                raise AssistError(f"shard {i}/{n} failed: {e.cause if e.cause else e}") from e
            except ray.exceptions.RayError as e:
                raise AssistError(
                    f"shard {i}/{n} was lost {max_retries + 1} times ({type(e).__name__}: {e}); "
                    f"run it again: assist.distributed.generate(…) remakes only what is missing"
                ) from e
            _check_visible(r, out)
            results[i] = r
            if progress:
                _progress(len(results), n, t0, "shards")
    st = status(out, shards=n)
    if not st["all_complete"]:
        raise AssistError(
            f"{out}: every shard reported done, but not all hold: "
            f"{[s['shard'] + ' ' + s['state'] for s in st['incomplete']]}"
        )
    m = merge(out, coco_masks=coco_masks)
    seconds = time.monotonic() - t0
    made = sum(r["made"] for r in results.values())
    return {
        "out": out,
        "shards": n,
        "samples": m["samples"],
        "made": made,
        "seconds": seconds,
        "samples_per_second": made / seconds if seconds > 0 else 0.0,
        "merged": m,
        "per_shard": [results[i] for i in range(n)],
    }


def _train_task(data, out, log, done, options):
    """One scene's training in a worker: resumed from its checkpoint if an earlier try
    left one, skipped if it finished; its events appended to `log` as JSON lines (steps
    at most every 5 s)."""
    import json

    out, done = Path(out), Path(done)
    if done.is_file() and out.exists():
        return {"scene": str(out), "skipped": True, "node": _where()}
    opts = dict(options)
    if out.exists():
        opts["resume"] = True
    with open(log, "a", encoding="utf-8") as f:
        last = [0.0]

        def record(e):
            now = time.monotonic()
            if e.get("event") == "step" and now - last[0] < 5.0:
                return
            last[0] = now
            f.write(json.dumps({"time": time.time(), **e}, default=str) + "\n")
            f.flush()

        record({"event": "task", "node": _where(), "resume": bool(opts.get("resume"))})
        try:
            report = dict(_train(data, str(out), callback=record, **opts))
        except AssistError as e:
            # Killed after its last save but before its record: nothing left to train.
            if "has already trained" not in str(e):
                raise
            report = {"resumed": "already at its iterations"}
    report.update(scene=str(out), log=str(log), node=_where())
    tmp = done.with_name(done.name + f".tmp-{os.getpid()}")
    tmp.write_text(json.dumps(report, indent=1, default=str))
    os.replace(tmp, done)
    return report


def train(
    datasets,
    out_dir,
    address=None,
    max_retries=3,
    cpus_per_scene=1,
    progress=True,
    **options,
):
    """Trains one scene per dataset as Ray tasks: `out_dir/NAME.assist` with its log
    `out_dir/NAME.log` (NAME: the dataset folder's name, made unique). `options` are
    `assist.train`'s (`iters=`, `max_time=`, `downscale=`, …). Scenes checkpoint as they
    train; a task lost with its node is retried up to `max_retries` times and resumes from
    its last checkpoint (with `max_time`, a resumed run's time counts from where it
    stopped). A finished scene is recorded in `NAME.done.json`, so running the same call
    again trains only what is not done. Returns each scene's report, in `datasets` order.
    """
    ray = _ray()
    _connect(ray, address)
    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    names, jobs = set(), []
    for d in datasets:
        d = Path(d).resolve()
        if not d.exists():
            raise AssistError(f"{d}: no such dataset")
        name, k = d.name, 1
        while name in names:
            k += 1
            name = f"{d.name}-{k}"
        names.add(name)
        jobs.append((str(d), out_dir / f"{name}.assist", out_dir / f"{name}.log", out_dir / f"{name}.done.json"))
    task = ray.remote(_train_task).options(
        num_cpus=cpus_per_scene,
        max_retries=max_retries,
        retry_exceptions=False,
        scheduling_strategy="SPREAD",
        runtime_env={"env_vars": {"RAYON_NUM_THREADS": str(max(1, int(cpus_per_scene)))}},
    )
    t0 = time.monotonic()
    pending = {
        task.remote(d, str(o), str(lg), str(dn), options): k for k, (d, o, lg, dn) in enumerate(jobs)
    }
    reports = [None] * len(jobs)
    while pending:
        ready, _ = ray.wait(list(pending), num_returns=1)
        for ref in ready:
            k = pending.pop(ref)
            try:
                reports[k] = ray.get(ref)
            except ray.exceptions.RayError as e:
                raise AssistError(f"training {jobs[k][0]} failed (its log: {jobs[k][2]}): {e}") from e
            if not Path(jobs[k][1]).exists():
                raise AssistError(
                    f"{jobs[k][0]} was trained on {reports[k].get('node')} but {jobs[k][1]} is not "
                    f"visible here: out_dir must be shared by every node and this driver"
                )
            if progress:
                _progress(sum(r is not None for r in reports), len(jobs), t0, "scenes")
    return reports
