"""Quadson, the five-bar-leg quadruped of seed 000: constants and MJCF generator."""
