"""The simulated camera's shape (issue 32): small classes, one dispatch table made of groups.

- (tests/test_shape.py holds its classes to 400 lines: the FPGA model was 851, the stepper
  controller 639, the camera 452, the stage 412, the stream engine 405);
- the FPGA's dispatch table, joined from its groups of command handlers, has exactly one
  handler for every command of config/protocol.toml, and a command claimed by two groups is
  refused when the table is made.
"""

from __future__ import annotations

import pytest

from camd.protocol import CommandSpec, load_dictionary
from camd.protocol.dictionary import FieldValue
from firmware_models.fpga import FpgaModel
from firmware_models.fpga_commands import Handler, Outcome, dispatch_table


def test_every_command_has_exactly_one_handler() -> None:
    model = FpgaModel(seed=0)
    try:
        commands = {spec.name for spec in load_dictionary().commands}
        assert len(commands) == 41
        assert set(model.link.table) == commands
    finally:
        model.close()


class _Group:
    def __init__(self, *names: str) -> None:
        self.names = names

    def handlers(self) -> dict[str, Handler]:
        def handler(spec: CommandSpec, request: dict[str, FieldValue], now_s: float) -> Outcome:
            return Outcome(b"")

        return dict.fromkeys(self.names, handler)


def test_a_command_claimed_by_two_groups_is_refused() -> None:
    assert sorted(dispatch_table([_Group("PING"), _Group("RESET")])) == ["PING", "RESET"]
    with pytest.raises(ValueError, match=r"^PING has a handler in two command groups$"):
        dispatch_table([_Group("PING", "RESET"), _Group("SET_MODE", "PING")])
