#!/usr/bin/env bash
# Trains seed 000's five gaits with their recipes (train/ppo_mjx.py --gait G), all at once on one GPU:
# the processes share the GPU, so one process's XLA compilation overlaps the others' training.
#
#   bash train/all_gaits.sh [OUT_DIR [OVERRIDE ...]]   # default results/gaits; logs in OUT_DIR/<gait>.log
#   GAITS="bound gallop" bash train/all_gaits.sh runs/b --env.reward.weights.contact_pattern=6
#
# OVERRIDEs (train/ppo_mjx.py's --env.* and --ppo.* flags) apply to every gait; GAITS picks the gaits
# (default all five). Steps per gait: walk and trot, which stay up open loop, need fewer than pace,
# bound and gallop. Each process takes XLA_PYTHON_CLIENT_MEM_FRACTION of the GPU's memory (default
# 0.12: up to seven fit on one H100).
set -u
out=${1:-results/gaits}
shift || true
mkdir -p "$out"
declare -A steps=([walk]=60000000 [trot]=60000000 [pace]=80000000 [bound]=80000000 [gallop]=80000000)
pids=()
for g in ${GAITS:-walk trot pace bound gallop}; do
  [ -n "${steps[$g]:-}" ] || { echo "error: unknown gait $g; choose from ${!steps[*]}" >&2; exit 2; }
  XLA_PYTHON_CLIENT_MEM_FRACTION=${XLA_PYTHON_CLIENT_MEM_FRACTION:-0.12} \
    python3 train/ppo_mjx.py --gait "$g" --run-dir "$out/$g" \
    --ppo.num_timesteps="${steps[$g]}" --ppo.num_evals=5 "$@" >"$out/$g.log" 2>&1 &
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
