#!/usr/bin/env bash
# Trains one policy across several hosts under SLURM: one task (process) per node, each using every
# GPU of its node; jax.distributed reads the coordinator, process count and index from SLURM
# (--distributed). Process 0 evaluates and writes the run directory; the others write nothing.
#
#   sbatch --nodes=2 train/launch_slurm.sh runs/two_hosts [--ppo.KEY=VALUE ...]
#   sbatch --nodes=2 train/launch_slurm.sh --resume runs/two_hosts     # continue it, same node count
#
# The run directory must be on a filesystem every node sees (a resume reads it on every node).
# ppo.num_envs and ppo.batch_size must divide by the total GPU count. scancel sends SIGTERM to every
# task: the run stops at its next safe point, resumable from process 0's last checkpoint.
# Open MPI instead of SLURM: mpirun -np NODES --map-by ppr:1:node python3 train/ppo_mjx.py --distributed ...
# Without a cluster manager, start on each host i (0 .. N-1), host0 being reachable by all:
#   python3 train/ppo_mjx.py --run-dir RUN --coordinator host0:1234 --num-processes N --process-id i
#SBATCH --job-name=quadson-train
#SBATCH --ntasks-per-node=1
#SBATCH --gpus-per-node=1
#SBATCH --time=01:00:00
#SBATCH --output=%x-%j.log
set -eu
if [ "${1:-}" = "--resume" ]; then
  args=(--resume "$2")
  shift 2
else
  args=(--run-dir "${1:?usage: launch_slurm.sh RUN_DIR [overrides] | --resume RUN_DIR}")
  shift
fi
# -u: unbuffered, so that every task's lines reach the log in order when one task fails
srun --kill-on-bad-exit=1 python3 -u train/ppo_mjx.py --distributed "${args[@]}" "$@"
