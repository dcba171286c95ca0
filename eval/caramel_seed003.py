"""Seed 003's experiments on the Caramel model: quadson_mjx.cli.seed003, the console command `quadson-seed003` (pip install -e .).

This path keeps working: `python eval/caramel_seed003.py ARGS` is `quadson-seed003 ARGS`.
"""

import sys

from quadson_mjx.cli.seed003 import main

if __name__ == "__main__":
    sys.exit(main())
