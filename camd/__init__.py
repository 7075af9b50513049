"""camd: hardware-in-the-loop control daemon for digital-TDI push-broom cameras."""

__version__ = "0.1.0"
