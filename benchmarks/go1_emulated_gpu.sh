#!/usr/bin/env bash
# The emulated Go1 loop with the MHE's line decisions on a GPU (`mhe: {attribute: true, attribute_device: cuda}`),
# as docs/evaluation.md measures it on a lent GPU host: Warp's kernel cache warmed once by one process (so no
# client compiles them mid-grid, and no two compile at once), then `go1_emulated_runs.py` over the tasks and
# seeds (two clients per GPU on a 16-CPU host with one, as many on each GPU of a larger one: `--gpus`), each run's
# JSON line appended to $OUT/rows.jsonl as it finishes (a call cut off keeps every finished run), its stderr to
# $OUT/grid.log, the table at the end.
#
# Usage (amhe's dependencies and amhe[gpu] importable, run from the repository's root; BELIEFS holds one
# starting belief per task, TASK.belief.yaml, e.g. from `amhe probe --target sim`):
#     OUT=results BELIEFS=dir benchmarks/go1_emulated_gpu.sh t3,t4 SEEDS [FIRST_SEED] [more go1_emulated_runs.py args]
# EXTRA_CONFIG adds lines to the runs' config: EXTRA_CONFIG='mhe_shadow: true' ... --label shadow runs the same
# client with its estimates only recorded (the planner keeps the belief): the estimator's load without its belief.
# Detached (`setsid`), it outlives the command that started it, so a later command can wait for its rows.
# The recordings worth reading (falls, trips, changes held after 3 s; at most 4) are copied to $OUT/kept, each with
# its last 10 s as NAME.tail.mcap (a few MB: a whole recording can be over what a lent host sends back), a
# folder a caller brings back before the host is returned with the rest.
set -u
OUT=${OUT:-gpu_loop}
BELIEFS=${BELIEFS:-.}
mkdir -p "$OUT"
here=$(cd "$(dirname "$0")" && pwd)
tasks=$1; seeds=$2; first=${3:-0}; shift $(( $# < 3 ? $# : 3 ))
mkdir -p "$OUT/recordings"
config="$OUT/attr.yaml"
printf 'mhe: {attribute: true, attribute_device: cuda}\nmhe_cores: 2\n%s\n' "${EXTRA_CONFIG:-}" > "$config"
first_task=${tasks%%,*}
t0=$(date +%s)
# a second of the wall-clock loop in the sim loads the decisions' backend before it (MovingHorizonEstimator.warm):
# the first time on a machine, that compiles MuJoCo Warp's kernels into its cache
python3 -c "from amhe_cli.cli import main; main()" run --task "$first_task" --mode adaptive --realtime --duration 1 -q --force \
    --belief "$BELIEFS/$first_task.belief.yaml" --config "$config" --out "$OUT/warm.mcap" > "$OUT/warm.log" 2>&1
echo "warm: rc $? in $(( $(date +%s) - t0 )) s" | tee -a "$OUT/grid.log"
rm -f "$OUT/warm.mcap" "$OUT/warm.truth.csv"
# every GPU of the host: the pairs the CPUs hold (6 + 1 each) spread over them, pair k on GPU k mod N
gpus=$(nvidia-smi -L 2>/dev/null | grep -c '^GPU')
python3 "$here/go1_emulated_runs.py" --tasks "$tasks" --modes adaptive --seeds "$seeds" --first-seed "$first" \
    --cores-per-run 6 --emulator-cores 1 --gpus "$gpus" --config "$config" --run-args "--belief $BELIEFS/{task}.belief.yaml" \
    --jsonl "$OUT/rows.jsonl" --out-dir "$OUT/recordings" --keep "$OUT/kept" "$@" >> "$OUT/grid.log" 2>&1
echo "grid: rc $? in $(( $(date +%s) - t0 )) s" | tee -a "$OUT/grid.log"
