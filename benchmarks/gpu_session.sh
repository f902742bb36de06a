#!/usr/bin/env bash
# Every GPU figure of docs/gpu.md in one run on a GPU machine, each written to $OUT as soon as it is known
# (a run cut off keeps what finished): the marked GPU tests, benchmarks/gpu_throughput.py (agreement,
# throughput against all CPU cores, identify in-process and as a user runs it, mhe-replay on the live
# clock), the planner's samples on the GPU against the CPU (gpu_planner.py), and identify's accuracy over
# 8 seeds on cuda.
#
# Usage (amhe, amhe[gpu] and pytest importable):
#     OUT=results benchmarks/gpu_session.sh CONST_A.mcap MHE_LOG.mcap [ACCURACY_LOG.mcap ...]
set -u
OUT=${OUT:-gpu_results}
mkdir -p "$OUT"
here=$(cd "$(dirname "$0")" && pwd)
const_a=$1; mhe_log=$2; shift 2
python3 -m pytest -q -m gpu "$here/../tests/test_gpu_backend.py" -p no:cacheprovider 2>&1 | tail -3 | tee "$OUT/pytest_gpu.txt"
python3 "$here/gpu_throughput.py" "$const_a" --batches 16384,32768 --repeats 2 --profile --cli --mhe "$mhe_log" \
    --out "$OUT" 2>&1 | grep -v "^ *[0-9/]* *[0-9.]* *0.00[0-9] "
python3 "$here/gpu_planner.py" --samples 16,256,1024 --out "$OUT/gpu_planner.jsonl" 2>&1 | grep -v Warning
if [ $# -gt 0 ]; then
    python3 "$here/identify_accuracy.py" "$@" --seeds 8 --jobs 2 --device cuda --out "$OUT/accuracy_cuda.jsonl" 2>&1 | tail -12
fi
