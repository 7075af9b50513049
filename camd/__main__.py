"""``python -m camd`` is the ``camd`` command (used where the console script is not on PATH)."""

import sys

from camd.cli.camd_main import main

sys.exit(main())
