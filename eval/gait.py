"""Run a gait open loop in the closed-chain model on CPU MuJoCo: quadson_mjx.cli.gait, the console command `quadson-gait` (pip install -e .).

This path keeps working: `python eval/gait.py ARGS` is `quadson-gait ARGS`.
"""

import sys

from quadson_mjx.cli.gait import main, run_trial  # noqa: F401 (tests/test_walk.py loads this file and uses run_trial)

if __name__ == "__main__":
    sys.exit(main())
