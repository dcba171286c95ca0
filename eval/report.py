"""Compare controllers from rollout MCAP files: quadson_mjx.cli.report, the console command `quadson-report` (pip install -e .).

This path keeps working: `python eval/report.py ARGS` is `quadson-report ARGS`.
"""

import sys

from quadson_mjx.cli.report import main

if __name__ == "__main__":
    sys.exit(main())
