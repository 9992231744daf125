#!/bin/bash
# The GPU figures of BENCHMARKS.md ("On a GPU") in one run, for a machine with a GPU and a
# Vulkan driver: the field's kernels at Nerfacto size (twice: a difference smaller than the
# two runs' spread is noise), at 1 M samples and at 64 samples per workgroup. With a desk
# dataset, also `bench train` 90 s on the CPU (issue 45's budget for desk), desk trained 90 s
# on the GPU, then its held-out views and frames on the CPU and the GPU. With lego_400 too,
# `bench train` 20 s (its budget) on each device.
#
#   scripts/gpu_bench.sh ASSIST_BINARY OUT_DIR [DESK_DIR [LEGO_DIR]]
#
# Prints a table last; the JSON of every run lands in OUT_DIR. Built for a lent device
# machine: carry a stripped release binary (and, where `ldconfig -p | grep libvulkan` is
# empty there, the Vulkan loader) and run this once.
set -u
bin=$1 out=$2 desk=${3:-} lego=${4:-}
mkdir -p "$out"
command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,driver_version,clocks.sm --format=csv

field() { # name, environment (K=V, or -), then bench field's arguments
    local name=$1 envs=$2
    shift 2
    [ "$envs" = - ] && envs=
    timeout 300 env $envs "$bin" bench field --device gpu --json "$@" >"$out/$name.json" 2>"$out/$name.err"
    echo "$name: exit $?"
}
field nerfacto - --nerfacto-only
field nerfacto.2 - --nerfacto-only
field 1m - --nerfacto-only --rays 16384
field tile64 ASSIST_GPU_TILE=64 --nerfacto-only

if [ -n "$desk" ]; then
    timeout 200 "$bin" bench train "$desk" --max-time 90 --device cpu --json >"$out/bench_train_cpu.json" 2>"$out/bench_train_cpu.err"
    timeout 200 "$bin" train "$desk" --out "$out/desk.assist" --max-time 90 --device gpu --json >"$out/train.json" 2>"$out/train.err"
    for d in cpu gpu; do
        timeout 200 "$bin" eval "$out/desk.assist" --data "$desk" --device $d --json >"$out/eval_$d.json" 2>"$out/eval_$d.err"
        timeout 300 "$bin" bench render "$out/desk.assist" --data "$desk" --prune-eps 0 --views 4 --runs 5 --device $d --json \
            >"$out/render_$d.json" 2>"$out/render_$d.err"
    done
fi

if [ -n "$lego" ]; then
    for d in gpu cpu; do
        timeout 150 "$bin" bench train "$lego" --max-time 20 --device $d --json >"$out/bench_train_lego_$d.json" 2>"$out/bench_train_lego_$d.err"
    done
fi

python3 - "$out" <<'PY'
import glob, json, os, sys
out = sys.argv[1]
def load(p):
    try:
        return json.load(open(p))
    except Exception as e:
        return None
print(f"{'run':12s} {'field':9s} {'train M/s':>9s} {'ms/step':>8s} {'infer M/s':>9s}  stages (ms)")
for p in sorted(glob.glob(os.path.join(out, "*.json"))):
    d = load(p)
    name = os.path.basename(p)[:-5]
    if not d or "fields" not in d:
        continue
    for f in d["fields"]:
        g = f.get("gpu") or {}
        if not g:
            print(name, "no GPU figures")
            continue
        st = " ".join(f"{k} {v * 1e3:.2f}" for k, v in g["train_stage_seconds"].items())
        print(f"{name:12s} {f.get('field', '?'):9s} {g['train_samples_per_sec'] / 1e6:9.2f} "
              f"{g['train_step_seconds'] * 1e3:8.2f} {g['infer_samples_per_sec'] / 1e6:9.1f}  {st}")
PY
if [ -n "$desk" ]; then
    for f in bench_train_cpu train eval_cpu eval_gpu render_cpu render_gpu; do echo "== $f"; tail -n 4 "$out/$f.err"; done
fi
[ -n "$lego" ] && for d in gpu cpu; do echo "== bench_train_lego_$d"; tail -n 4 "$out/bench_train_lego_$d.err"; done
