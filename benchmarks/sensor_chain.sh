#!/usr/bin/env bash
# The sensor-only joystick recipe's two stages as one command (train/recipes/joystick_10min.args;
# docs/results.md, "A first stage at 5 ms"), several variants at once, one per GPU, each from an
# empty compilation cache and timed from launch to exit; then each fine-tuned policy on the issue's
# sweep on the same GPU (2 ms, the stones, randomized, sensor errors and pushes, 75 commands x 4
# environments x 20 s).
# Usage: bash benchmarks/sensor_chain.sh OUT_DIR "NAME:ARGS" ... (one variant per GPU; ARGS are added
# to the chain's command, --finetune.KEY=VALUE for the fine-tune alone):
#   bash benchmarks/sensor_chain.sh results/policy_h200_sensors_e16u10/comparison \
#       "chain_a:--ppo.seed=5" "chain_b:--ppo.seed=6 --finetune.ppo.num_timesteps=48000000 --finetune.ppo.num_evals=4"
# OUT_DIR/NAME/ gets the first stage's run (config, MCAP log, its newest checkpoint), the console
# with the command's wall clock (train_console.log), finetune/ (the same) and eval_dt2.{json,log}.
# STAGE1_STEPS, FT_STEPS, ENVS, BATCH and SWEEP (the sweep's --seconds and --replicas; none: no
# sweep) change the recipe's; KEEP_STEPS="N ..." keeps the first stage's checkpoints at those steps
# too (for fine-tunes from them later); a quick try on the CPU (no GPU: the variants share it):
#   ENVS=16 BATCH=16 STAGE1_STEPS=20480 FT_STEPS=20480 SWEEP="--seconds 1.2 --replicas 1" bash ...
set -u
out=${1:?usage: sensor_chain.sh OUT_DIR NAME:ARGS [NAME:ARGS ...]}
shift
[ $# -gt 0 ] || { echo "error: name at least one variant, NAME:ARGS" >&2; exit 2; }
n_gpus=$(nvidia-smi -L 2>/dev/null | grep -c '^GPU')
[ "$n_gpus" -eq 0 ] || [ $# -le "$n_gpus" ] || { echo "error: $# variants for $n_gpus GPUs: one a GPU" >&2; exit 2; }
for v in "$@"; do
  name=${v%%:*}
  [[ $v == *:* && $name =~ ^[A-Za-z0-9_.-]+$ ]] || { echo "error: variant '$v' is not NAME:ARGS" >&2; exit 2; }
  [ ! -e "$out/$name" ] || { echo "error: $out/$name exists; choose another name" >&2; exit 2; }
done
mkdir -p "$out"
recipe="@train/recipes/joystick_10min.args"  # the recipe's flags, then the changes asked for
for kv in ENVS:ppo.num_envs BATCH:ppo.batch_size STAGE1_STEPS:ppo.num_timesteps FT_STEPS:finetune.ppo.num_timesteps; do
  var=${kv%%:*}
  [ -z "${!var:-}" ] || recipe+=" --${kv#*:}=${!var}"
done

one() {  # gpu name args
  local gpu=$1 args=$3 dir=$out/$2 log
  log=$(mktemp)
  local cache
  cache=$(mktemp -d)
  local t0
  t0=$(date +%s.%N)
  # shellcheck disable=SC2086  # recipe and args hold several words
  CUDA_VISIBLE_DEVICES=$gpu python3 train/ppo_mjx.py $recipe $args --compile-cache "$cache" \
    --run-dir "$dir" --finetune-run-dir "$dir/finetune" > "$log" 2>&1
  local rc=$?
  printf '\n# the command'"'"'s wall clock (bash, around the process): exit %d wall %.1f s\n' \
    "$rc" "$(python3 -c "import time; print(time.time() - $t0)")" >> "$log"
  mkdir -p "$dir" && mv "$log" "$dir/train_console.log"
  rm -rf "$cache"
  local keep=() k  # the first stage's checkpoints at KEEP_STEPS, besides each stage's newest
  for k in ${KEEP_STEPS:-}; do keep+=(! -name "$(printf 'step_%012d.msgpack' "$k")"); done
  for ck in "$dir/checkpoints" "$dir/finetune/checkpoints"; do  # each stage's newest checkpoint only
    [ -d "$ck" ] || continue
    last=$(find "$ck" -name 'step_*.msgpack' | sort | tail -1)
    find "$ck" \( -name 'step_*.msgpack' -o -name 'state_*.npz' \) ! -path "$last" "${keep[@]}" -exec rm -f {} {}.sha256 \;
    keep=()
  done
  [ "$rc" -eq 0 ] && [ "${SWEEP:-}" != none ] || return
  # shellcheck disable=SC2086  # SWEEP holds several words
  CUDA_VISIBLE_DEVICES=$gpu python3 -m quadson_mjx.cli.policy_eval ${SWEEP:---seconds 20 --replicas 4} --terrain rough \
    --env.sim_dt=0.002 --policy "$dir/finetune" --out "$dir/eval_dt2.json" > "$dir/eval_dt2.log" 2>&1
}

gpu=0
for v in "$@"; do
  one "$gpu" "${v%%:*}" "${v#*:}" &
  gpu=$((gpu + 1))
done
wait
for v in "$@"; do
  dir=$out/${v%%:*}
  echo "== ${v%%:*}: $(tail -1 "$dir/train_console.log")"
  [ -f "$dir/eval_dt2.log" ] && grep -v 'Delay kernel' "$dir/eval_dt2.log"
done
