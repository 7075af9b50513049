"""Motion: the scan stage kept in step with the TDI line period, and the filter wheel.

``stage_profile`` and ``wheel_profile`` are data (the mechanics of config/stages/ and
config/wheel.toml, validated by pydantic) and pure, so the simulated camera reads the same files.
"""
