"""Sim-to-sim evaluation of exported policies: quadson_mjx.cli.sim2sim, the console command `quadson-sim2sim` (pip install -e .).

This path keeps working: `python eval/sim2sim.py ARGS` is `quadson-sim2sim ARGS`.
"""

import sys

from quadson_mjx.cli.sim2sim import main

if __name__ == "__main__":
    sys.exit(main())
