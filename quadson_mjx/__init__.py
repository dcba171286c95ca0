"""quadson_mjx: kinematics, gaits, a closed-chain MuJoCo model and an MJX environment for Quadson."""

__version__ = "0.1.0"
