"""One package per robot (the layout of mujoco_playground / mujoco_menagerie): constants, MJCF generator,
gait and experiments of a robot live in its own folder (quadson/, caramel/); leg kinematics, gait,
rewards, environment and training shared by the robots stay at the package top level."""
