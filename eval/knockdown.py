"""Knocked down while walking, over many randomized knock-downs: quadson_mjx.cli.knockdown, the console command `quadson-knockdown` (pip install -e .).

This path keeps working: `python eval/knockdown.py ARGS` is `quadson-knockdown ARGS`.
"""

import sys

from quadson_mjx.cli.knockdown import main

if __name__ == "__main__":
    sys.exit(main())
