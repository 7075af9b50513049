"""The simulated device's refusal: what a command handler raises to answer with a NAK."""

from __future__ import annotations


class Nak(Exception):
    """Refuse a command: ``error`` is an error name of config/protocol.toml, ``detail`` the words
    the operator sees (what was wrong and what to change)."""

    def __init__(self, error: str, detail: str) -> None:
        super().__init__(detail)
        self.error = error
        self.detail = detail
