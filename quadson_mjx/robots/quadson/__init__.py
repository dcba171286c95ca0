"""Quadson, the five-bar-leg quadruped of seed 000: constants, five-bar kinematics (fivebar), body frames
(body), gait table (gait; numpy twin gait_np for the robot's computer), MJCF generator (model), robot."""
