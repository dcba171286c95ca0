"""Caramel, the serial-leg quadruped of seed 003: constants, MJCF generator, trot planner, experiments."""
