"""Seed 000's five gaits over many randomized episodes: quadson_mjx.cli.gaits, the console command `quadson-gaits` (pip install -e .).

This path keeps working: `python eval/gaits.py ARGS` is `quadson-gaits ARGS`.
"""

import sys

from quadson_mjx.cli.gaits import main

if __name__ == "__main__":
    sys.exit(main())
