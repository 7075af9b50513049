"""Shared test configuration."""

from __future__ import annotations

from hypothesis import settings

# No per-example deadline: CI machines are slow and shared; a slow example is not a failure.
settings.register_profile("camd", deadline=None)
settings.load_profile("camd")
