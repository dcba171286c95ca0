"""Run a gait open loop in the closed-chain model on CPU MuJoCo: quadson_mjx.cli.gait, the console command `quadson-gait` (pip install -e .).

This path keeps working: `python eval/gait.py ARGS` is `quadson-gait ARGS`.
"""

import sys

from quadson_mjx.cli.gait import main

if __name__ == "__main__":
    sys.exit(main())
