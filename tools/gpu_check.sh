#!/bin/bash
# The GPU measurements of README "Benchmarks" in one command, for a GPU session of a few minutes:
#
#     tools/gpu_check.sh OUT [PYTHON]        # OUT: a folder for the JSON and logs; PYTHON: default python3
#
# 1. the stage tests against their numpy twins on this adapter, and the pipeline-state fault and
#    bench tests (pytest -n 8 where pytest-xdist is installed); 2. tools/bench.py at 100k and 1M primitives, 256 and 512 px, K = 1 and 8, each with
#    both compositor shapes ("lanes" and "wide", and whether their frames are bit-equal), K = 8
#    also with its views one at a time against batched (--one-by-one, on by default on a GPU), with
#    the compositing-chunk sweep for each shape and a 20,000-injection campaign; 3. tools/memory.py at 10M and 100M
#    primitives (100M measured on an H200, 2026-11-26: 42,893 MiB of device buffers, 44.2 GiB of host
#    memory at peak; README "100M primitives, measured"). Each step has its
#    own time limit (SECONDS_TESTS, SECONDS_BENCH, SECONDS_MEMORY) and writes its log as it goes, so
#    a step cut short leaves the others' results; a limit of 0 skips its step (e.g.
#    SECONDS_MEMORY=0 where 100M has been measured already and device time is short).
set -u
OUT=${1:?usage: tools/gpu_check.sh OUT [PYTHON]}
PY=${2:-python3}
mkdir -p "$OUT" && OUT=$(cd "$OUT" && pwd)  # absolute: the script runs from the repository root
PY=$(command -v "$PY" || realpath "$PY")
cd "$(dirname "$0")/.." || exit 1
export PYTHONUNBUFFERED=1
$PY -c "import wgpu; a = wgpu.gpu.request_adapter_sync(power_preference='high-performance'); print(a.info)" \
    2>&1 | tee "$OUT/adapter.txt"
XDIST=$($PY -c "import xdist" 2>/dev/null && echo "-n 8")
step() {  # step LIMIT_SECONDS COMMAND...: run under `timeout`, or skip when the limit is 0
    if [ "$1" = 0 ]; then echo "skipped (limit 0)"; return 0; fi
    timeout "$@"
}
step "${SECONDS_TESTS:-150}" $PY -m pytest -q -p no:cacheprovider $XDIST tests/test_project.py tests/test_bin.py \
    tests/test_sort.py tests/test_composite.py tests/test_render.py tests/test_render_sort.py tests/test_incremental.py \
    tests/test_split.py tests/test_decode.py tests/test_guard_faults.py tests/test_guard_nonfinite.py tests/test_kernel.py \
    tests/test_reference.py tests/test_state.py tests/test_bench.py > "$OUT/tests.txt" 2>&1
echo "tests: exit $?" | tee -a "$OUT/tests.txt"
step "${SECONDS_BENCH:-300}" $PY tools/bench.py --scenes spheres --n 100000 1000000 --sizes 256 512 --views 1 8 \
    --repeats 10 --budget 3 --twin-views 1 --twin-max-n 100000 --campaign-samples 20000 \
    --chunks 8192 2048 512 --out "$OUT/bench.json" > "$OUT/bench.txt" 2>&1
echo "bench: exit $?" | tee -a "$OUT/bench.txt"
step "${SECONDS_MEMORY:-360}" $PY tools/memory.py --scene spheres --n 10000000 100000000 --size 256x256 \
    --json "$OUT/memory.json" > "$OUT/memory.txt" 2>&1
echo "memory: exit $?" | tee -a "$OUT/memory.txt"
tail -n 3 "$OUT/tests.txt" "$OUT/memory.txt"
