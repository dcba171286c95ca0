"""One package per robot (the layout of mujoco_playground / mujoco_menagerie): constants, MJCF generator,
gait and experiments of a robot live in its own folder. Quadson's modules are still at the package top
level (quadson_mjx.constants, quadson_mjx.model)."""
