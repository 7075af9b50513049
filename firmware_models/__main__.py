"""``python -m firmware_models``: run the simulated camera (see firmware_models.cli)."""

from firmware_models.cli import main

raise SystemExit(main())
