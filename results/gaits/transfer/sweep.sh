#!/usr/bin/env bash
# Fine-tunes of the bound for MuJoCo C: each variant continues FROM (default results/gaits/bound; --init-from) with
# its overrides, all at once on one GPU (a share of its memory each), STEPS steps (default 40M) with
# a checkpoint every STEPS / 5 (TRAIN_LIMIT_S: stop each training after that many seconds, at its
# last checkpoint); then every variant and the committed bound are exported and run 30 seeds through
# the robot's deploy loop against MuJoCo C under two fixed sets of model ranges, whatever a variant
# trained on (the committed bound's trained ones; the MJX gait evaluation's), and every variant is
# evaluated in MJX on each of EVAL_SEEDS (default 1) under the gait evaluation's ranges.
#   bash results/gaits/transfer/sweep.sh OUT_DIR "NAME:TRAIN ARGS" ...
# A variant named NAME@RUN continues RUN instead of FROM. TRAIN=only stops after the trainings;
# TRAIN=0 skips them and evaluates the runs already in OUT_DIR (a second command on the same machine).
# Output: OUT_DIR/NAME/bound (the run), OUT_DIR/NAME.npz, OUT_DIR/sim2sim_{trained,evaluated}/,
# OUT_DIR/eval_NAME_sS.{json,log}, OUT_DIR/NAME.console (the training's console).
set -u
out=${1:?usage: sweep.sh OUT_DIR NAME:ARGS ...}
shift
[ $# -gt 0 ] || { echo "sweep.sh: no variants" >&2; exit 2; }
mkdir -p "$out"
export XLA_PYTHON_CLIENT_MEM_FRACTION=${XLA_PYTHON_CLIENT_MEM_FRACTION:-0.2}
steps=${STEPS:-40000000}
pids=()
names=()
for v in "$@"; do
  name=${v%%:*}
  args=${v#*:}
  from=${FROM:-results/gaits/bound}
  if [[ $name == *@* ]]; then from=${name#*@}; name=${name%%@*}; fi
  names+=("$name")
  [ "${TRAIN:-1}" = 0 ] && continue
  # shellcheck disable=SC2086  # args holds several words
  timeout -s TERM "${TRAIN_LIMIT_S:-100000}" python3 train/ppo_mjx.py --init-from "$from" \
    --run-dir "$out/$name/bound" --ppo.num_timesteps="$steps" --ppo.num_evals=5 $args \
    > "$out/$name.console" 2>&1 &
  pids+=($!)
done
for p in "${pids[@]}"; do wait "$p"; done
[ "${TRAIN:-1}" = only ] && exit 0
python3 -m quadson_mjx.export results/gaits/bound "$out/committed.npz" > /dev/null || exit 1
policies=("$out/committed.npz")
for name in "${names[@]}"; do
  python3 -m quadson_mjx.export "$out/$name/bound" "$out/$name.npz" > /dev/null && policies+=("$out/$name.npz")
done
# the model ranges of the MuJoCo C runs: the committed bound's trained ones, and the MJX
# evaluation's (friction as trained)
trained=(--randomization friction=0.5,1.2 --randomization mass_scale=0.85,1.25
  --randomization motor_strength=0.8,1.2 --randomization base_com_shift_m=-0.02,0.03)
evaluated=(--randomization friction=0.5,1.2 --randomization mass_scale=0.85,1.15
  --randomization motor_strength=0.8,1.2 --randomization base_com_shift_m=-0.02,0.02)
for set in trained evaluated; do
  declare -n r=$set
  python3 eval/sim2sim.py "${policies[@]}" --commands gait --terrain flat --seconds 20 --seeds 30 \
    --latency-ms 20 --randomize "${r[@]}" --mcap none --workers "${WORKERS:-6}" \
    --out "$out/sim2sim_$set" > "$out/sim2sim_$set.log" 2>&1 &
done
export XLA_PYTHON_CLIENT_MEM_FRACTION=0.08
for name in "${names[@]}"; do
  for s in ${EVAL_SEEDS:-1}; do
    python3 eval/gaits.py --runs "$out/$name" --gaits bound --controllers policy --envs 256 --seed "$s" \
      --randomization mass_scale=0.85,1.15 --randomization base_com_shift_m=-0.02,0.02 \
      --randomization motor_strength=0.8,1.2 --json "$out/eval_${name}_s$s.json" \
      > "$out/eval_${name}_s$s.log" 2>&1 &
  done
done
wait
cat "$out"/sim2sim_*.log
for f in "$out"/eval_*.log; do echo "== $f"; cat "$f"; done
