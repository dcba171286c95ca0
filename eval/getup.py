"""A trained get-up policy over many drops, per start class: quadson_mjx.cli.getup_eval, the console command `quadson-getup-eval` (pip install -e .).

This path keeps working: `python eval/getup.py ARGS` is `quadson-getup-eval ARGS`.
"""

import sys

from quadson_mjx.cli.getup_eval import main

if __name__ == "__main__":
    sys.exit(main())
