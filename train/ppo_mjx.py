"""Train a policy with brax PPO on MJX: quadson_mjx.cli.train, the console command `quadson-train` (pip install -e .).

This path keeps working: `python train/ppo_mjx.py ARGS` is `quadson-train ARGS`.
"""

import sys

from quadson_mjx.cli.train import main

if __name__ == "__main__":
    sys.exit(main())
