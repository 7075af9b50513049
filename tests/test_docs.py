"""docs/protocol.md is generated from the dictionary and must never drift from it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from camd.protocol import load_dictionary
from camd.protocol.docgen import main, render_protocol_doc

ROOT = Path(__file__).resolve().parents[1]
PROTOCOL_MD = ROOT / "docs" / "protocol.md"


def test_protocol_md_matches_the_shipped_dictionary() -> None:
    expected = render_protocol_doc(load_dictionary())
    assert PROTOCOL_MD.read_text(encoding="utf-8") == expected, (
        "docs/protocol.md is stale: run `python -m camd.protocol.docgen` and commit the result"
    )


def test_render_contains_the_hand_checked_facts() -> None:
    text = render_protocol_doc(load_dictionary())
    # SET_MODE(tdi), seq 5: CRC-16/CCITT-FALSE of 01 05 05 00 01 01 is 0xF7B2 (bitwise reference
    # in test_protocol_frame.py); the ACK's, of 02 05 05 00 01 01, is 0x3952.
    assert "EB 90 01 05 05 00 01 01 F7 B2" in text
    assert "EB 90 02 05 05 00 01 01 39 52" in text
    assert "`123456789` is 0x29B1" in text
    assert "| 5 | 2 | payload length *n* | 0 .. 1024 |" in text
    assert "Opcodes 0xF0 .. 0xFF are implemented only by the simulated camera" in text
    d = load_dictionary()
    for c in d.commands:
        assert f"### 0x{c.opcode:02X} {c.name}" in text
    for p in d.telemetry + d.events:
        assert f"### 0x{p.opcode:02X} {p.name}" in text
    for e in d.errors:
        assert f"| {e.code} | {e.name} | {e.message} |" in text
    # Ranges in physical units with the scale and unit in their own columns.
    assert (
        "| 4 | 2 | `fpga_temp_degc` | i16 | 0.01 | degC | -327.68 .. 327.67 | FPGA die temperature |"
        in text
    )
    assert "| 0 | 1 | `mode` | u8 |  |  | `area` = 0, `tdi` = 1 | imaging mode |" in text


SMALL = """
version = 3

[[errors]]
code = 9
name = "NOPE"
message = "not today"

[[commands]]
name = "HELLO"
opcode = 0x20
doc = "Say | hello."
request = [{ name = "who", type = "str", max_len = 8, doc = "name" }]
"""


def test_render_of_another_dictionary(tmp_path: Path) -> None:
    path = tmp_path / "small.toml"
    path.write_text(SMALL)
    text = render_protocol_doc(load_dictionary(path))
    assert "(`config/protocol.toml`, version 3)" in text
    assert "### 0x20 HELLO" in text
    assert "Say \\| hello." in text  # a pipe in a doc string does not break the table
    assert "| 0 | 0 .. 8 | `who` | str |  |  | 0 .. 8 bytes of UTF-8 | name |" in text
    assert text.count("None.") == 2  # no telemetry packets, no events
    assert "hardware answers them with NAK." in text  # no UNKNOWN_OPCODE in this dictionary


def test_check_mode(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "docs" / "protocol.md"
    assert main(["--check", "--output", str(out)]) == 1
    assert "is missing: run `python -m camd.protocol.docgen`" in capsys.readouterr().err
    assert main(["--output", str(out)]) == 0
    assert out.read_text(encoding="utf-8") == render_protocol_doc(load_dictionary())
    assert main(["--check", "--output", str(out)]) == 0
    assert "is up to date" in capsys.readouterr().out
    out.write_text(out.read_text(encoding="utf-8").replace("0x29B1", "0x29B2"))
    assert main(["--check", "--output", str(out)]) == 1
    assert f"{out} is stale: run `python -m camd.protocol.docgen`" in capsys.readouterr().err


def test_bad_dictionary_is_reported(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("version = 0\n")
    assert main(["--dictionary", str(bad), "--output", str(tmp_path / "p.md")]) == 2
    assert f"{bad}:1: version: 0 is out of range; allowed: 1 <= version" in capsys.readouterr().err
    assert not (tmp_path / "p.md").exists()


def test_module_entry_point_checks_the_committed_file() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "camd.protocol.docgen", "--check"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    assert "protocol.md is up to date" in result.stdout
