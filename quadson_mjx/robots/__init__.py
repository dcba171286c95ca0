"""One package per robot (the layout of mujoco_playground / mujoco_menagerie): constants, MJCF generator,
gait and experiments of a robot live in its own folder (quadson/, caramel/); leg kinematics, gaits,
swing curves, the stabilizer and the reward terms stay at the package top level. The environment
(quadson_mjx.env) and training still run Quadson only."""
