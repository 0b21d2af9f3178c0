"""`python -m mogo ...` is the `mogo` command (torchrun launches training this way)."""

import sys

from mogo.cli import main

sys.exit(main())
