"""Headless rollouts of a controller to MCAP files: quadson_mjx.cli.rollout, the console command `quadson-rollout` (pip install -e .).

This path keeps working: `python eval/rollout.py ARGS` is `quadson-rollout ARGS`.
"""

import sys

from quadson_mjx.cli.rollout import main

if __name__ == "__main__":
    sys.exit(main())
