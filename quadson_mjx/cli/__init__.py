"""The command-line programs, the top layer (console entry points in pyproject.toml):

    quadson-train     quadson_mjx.cli.train     train a policy (brax PPO on MJX); --task NAME, --list-tasks
    quadson-rollout   quadson_mjx.cli.rollout   rollouts of a controller or policy to MCAP files
    quadson-report    quadson_mjx.cli.report    tables and plots comparing rollout MCAP files
    quadson-gaits     quadson_mjx.cli.gaits     seed 000's five gaits over randomized episodes
    quadson-gait      quadson_mjx.cli.gait      one gait open loop in CPU MuJoCo (seed 003 Table II)
    quadson-seed003   quadson_mjx.cli.seed003   seed 003's Tables I-III on the Caramel model

Each module parses its arguments and calls the library; `main(argv=None) -> int` is the exit status.
The old script paths (train/ppo_mjx.py, eval/*.py) import these `main`s.
"""
