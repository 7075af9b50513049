"""``python -m firmware_models``: run the simulated camera (see firmware_models.cli).

Once ``main`` returns, the simulator has closed its pty, its sockets and its servers and has
nothing left to save, so it ends there (``os._exit``): the interpreter's teardown of its modules
and arrays took 0.1-0.5 s that every daemon's stop waited for (camd/daemon/simulator.py). An
error out of ``main`` still ends the usual way, with its traceback.
"""

import logging
import os
import sys

from firmware_models.cli import main

status = main()
logging.shutdown()
sys.stdout.flush()
sys.stderr.flush()
os._exit(status)
