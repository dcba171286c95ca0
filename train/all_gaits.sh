#!/usr/bin/env bash
# Trains seed 000's five gaits with their recipes (train/ppo_mjx.py --gait G), all at once on one GPU:
# five processes share the GPU, so one process's XLA compilation overlaps the others' training.
#
#   bash train/all_gaits.sh [OUT_DIR]            # default results/gaits; logs in OUT_DIR/<gait>.log
#
# Steps per gait: the three gaits that stay up open loop need fewer than bound and gallop, which fall
# open loop within 1-2 s. Each process takes 18 % of the GPU's memory (five fit on one H100).
set -u
out=${1:-results/gaits}
mkdir -p "$out"
declare -A steps=([walk]=30000000 [trot]=30000000 [pace]=80000000 [bound]=80000000 [gallop]=80000000)
pids=()
for g in walk trot pace bound gallop; do
  XLA_PYTHON_CLIENT_MEM_FRACTION=${XLA_PYTHON_CLIENT_MEM_FRACTION:-0.18} \
    python3 train/ppo_mjx.py --gait "$g" --run-dir "$out/$g" \
    --ppo.num_timesteps="${steps[$g]}" --ppo.num_evals=5 >"$out/$g.log" 2>&1 &
  pids+=($!)
done
# a SIGTERM or SIGINT (timeout, Ctrl-C) reaches every training, which saves and stops at a safe point
trap 'kill -TERM "${pids[@]}" 2>/dev/null' TERM INT
status=0
for p in "${pids[@]}"; do
  while true; do
    wait "$p"; rc=$?
    kill -0 "$p" 2>/dev/null || break  # wait returned early for a trapped signal: wait again
  done
  [ "$rc" -eq 0 ] || status=1
done
exit $status
