"""The camera's state as the device itself reports it, to compare before and after a request.

It lives in ``camd.bench.device_snapshot`` (``camd bench fuzz`` checks it too); the tests import
it from here.
"""

from __future__ import annotations

from camd.bench.device_snapshot import snapshot

__all__ = ["snapshot"]
