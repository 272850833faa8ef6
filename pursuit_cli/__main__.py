"""`python -m pursuit_cli ...` runs the `pursuit-mj` command (where the script is not on PATH)."""

import sys

from pursuit_cli import main

sys.exit(main())
