#!/usr/bin/env bash
# Sample efficiency of the main job under PPO settings: every variant runs `python train/ppo_mjx.py`
# with its overrides, all at once on one GPU (a share of its memory each), 40M steps with an
# evaluation every 4M (STEPS and EVALS in the environment change the 40M and the 11 evaluations),
# so what compares is the environment steps to the first evaluation at or over 0.45 m/s and the
# speed at equal steps. Their wall-clock times are not comparable (the runs share the GPU); time a
# chosen variant alone with benchmarks/time_to_policy.py.
# Output: OUT_DIR/sweep.json (benchmarks/time_to_policy.py's records) and OUT_DIR/<name>.log.
# Variants after OUT_DIR ("NAME:TRAIN ARGS" each) replace the default five.
#   bash benchmarks/ppo_settings_sweep.sh benchmarks/results/ppo_settings_h200
#   bash benchmarks/ppo_settings_sweep.sh OUT "preset:" "lr_1e-3:--ppo.learning_rate=0.001"
set -u
out=${1:?usage: ppo_settings_sweep.sh OUT_DIR [NAME:ARGS ...]}
shift
mkdir -p "$out"
here=$(cd "$(dirname "$0")" && pwd)
variants=(
  "preset:"
  "gait_normal_0.1:--ppo.policy_distribution=gait_normal --ppo.init_noise_std=0.1"
  "gait_normal_0.3:--ppo.policy_distribution=gait_normal --ppo.init_noise_std=0.3"
  "lr_1e-3:--ppo.learning_rate=0.001"
  "envs_4096:--ppo.num_envs=4096 --ppo.batch_size=512"
)
[ $# -gt 0 ] && variants=("$@")
export XLA_PYTHON_CLIENT_MEM_FRACTION=${XLA_PYTHON_CLIENT_MEM_FRACTION:-0.18}
pids=()
for v in "${variants[@]}"; do
  name=${v%%:*}
  args=${v#*:}
  # shellcheck disable=SC2086  # args holds several words
  python3 "$here/time_to_policy.py" --name "$name" --out "$out/$name.json" --log "$out/$name.log" -- \
    --ppo.num_timesteps="${STEPS:-40000000}" --ppo.num_evals="${EVALS:-11}" $args > "$out/$name.summary" 2>&1 &
  pids+=($!)
done
for p in "${pids[@]}"; do wait "$p"; done
python3 - "$out" <<'PY'
import json, sys
from pathlib import Path
out = Path(sys.argv[1])
rows = [json.loads(p.read_text())[-1] for p in sorted(out.glob("*.json")) if p.name != "sweep.json"]
(out / "sweep.json").write_text(json.dumps(rows, indent=1))
steps = sorted({e["step"] for r in rows for e in r["evaluations"]})
print("speed [m/s] at each evaluation; * first at or over 0.45 m/s")
print("variant".ljust(18) + "".join(f"{s / 1e6:>7.0f}M" for s in steps))
for r in rows:
    at = {e["step"]: e["speed"] for e in r["evaluations"]}
    cells = []
    for s in steps:
        v = at.get(s)
        mark = "*" if v is not None and r["steps_to_target"] == s else " "
        cells.append("       -" if v is None else f"{v:7.3f}{mark}")
    print(r["name"].ljust(18) + "".join(cells), f" rc={r['returncode']}")
PY
