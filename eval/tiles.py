"""A trained policy on the tiled ground, per tile type and level: quadson_mjx.cli.tiles_eval, the console command `quadson-tiles-eval` (pip install -e .).

This path keeps working: `python eval/tiles.py ARGS` is `quadson-tiles-eval ARGS`.
"""

import sys

from quadson_mjx.cli.tiles_eval import main

if __name__ == "__main__":
    sys.exit(main())
