"""Caramel, the serial-leg quadruped of seed 003: constants, MJCF generator, trot planner (its experiments: quadson_mjx.seed003)."""
