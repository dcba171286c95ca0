"""quadson_mjx: kinematics, gaits, a closed-chain MuJoCo model and an MJX environment for Quadson."""

from quadson_mjx import warp_notice

__version__ = "0.1.0"

warp_notice.install()  # mujoco.mjx's "Failed to import warp" only for who asks for warp (env.impl)
