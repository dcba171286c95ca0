#!/usr/bin/env bash
# How much of the main job's training time is brax's PPO update: the same job (24M steps, 4
# evaluations) with fewer update passes per batch and with smaller networks, one after another on
# one GPU. The steps/s that brax reports after the first epoch is the number to compare (the first
# epoch includes compilation). Output: OUT_DIR/update_<name>.log.
#   bash benchmarks/ppo_update_profile.sh benchmarks/results/ppo_profile_h100
set -u
out=${1:?usage: ppo_update_profile.sh OUT_DIR}
mkdir -p "$out"
for v in "base:" "upb1:--ppo.num_updates_per_batch=1" "upb2:--ppo.num_updates_per_batch=2" \
    "small_nets:--ppo.policy_hidden=(64,64) --ppo.value_hidden=(128,128)"; do
  name=${v%%:*}
  args=${v#*:}
  # shellcheck disable=SC2086  # args holds several words
  timeout 170 python3 -m quadson_mjx.cli.train --ppo.num_timesteps=24000000 --ppo.num_evals=4 \
    --compile-cache /tmp/ppo_profile_cache --run-dir "/tmp/ppo_profile_$name" $args > "$out/update_$name.log" 2>&1
  echo "$name rc=$? $(grep -o '[0-9,]* steps/s' "$out/update_$name.log" | tail -1)"
done
