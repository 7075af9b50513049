"""docs/sensors.md is generated from the register-map schema and the shipped maps; never stale."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from pydantic import BaseModel

from camd.sensor.docgen import main, render_sensors_doc, shipped_maps
from camd.sensor.regmap import (
    FieldSpec,
    GroupSpec,
    OutputSpec,
    RegisterMap,
    RegisterSpec,
    SoftResetSpec,
    SpiLayout,
    TimingSpec,
    load_register_map,
)

ROOT = Path(__file__).resolve().parents[1]
SENSORS_MD = ROOT / "docs" / "sensors.md"


def test_sensors_md_matches_the_shipped_maps() -> None:
    expected = render_sensors_doc(shipped_maps())
    assert SENSORS_MD.read_text(encoding="utf-8") == expected, (
        "docs/sensors.md is stale: run `python -m camd.sensor.docgen` and commit the result"
    )


@pytest.mark.parametrize(
    "model",
    [RegisterMap, SpiLayout, TimingSpec, OutputSpec, SoftResetSpec, RegisterSpec, FieldSpec, GroupSpec],
)  # fmt: skip
def test_every_schema_key_is_documented(model: type[BaseModel]) -> None:
    text = render_sensors_doc(shipped_maps())
    for name, info in model.model_fields.items():
        assert f"| `{name}` |" in text, name
        assert info.description, f"{model.__name__}.{name} has no description"


def test_render_contains_the_hand_checked_facts() -> None:
    text = render_sensors_doc(shipped_maps())
    for regmap in shipped_maps():
        assert f"## {3 + shipped_maps().index(regmap)}. {regmap.sensor}" in text
        for reg in regmap.registers:
            assert f"| 0x{reg.address:02X} | `{reg.name}` | {reg.width} |" in text
    # HR400: 513 clocks at 25 MHz; the mission window and n = 2 give 537 lines.
    assert "Model `sequencer`: T_line = 513 clocks / 25 MHz (docs/physics.md §3)." in text
    assert "| line period T_line | 20.52 µs |" in text
    assert "| first frame (n + k + 1) T_line | 11.01924 ms |" in text
    # MT9M001 datasheet: 1524 pixel clocks at 48 MHz.
    assert "| line period T_line | 31.75 µs |" in text
    assert (
        "| `ROW_SIZE` | `rows_minus_1` | 10..0 | 2 .. 1023 (count = raw + 1) | row |  |  |" in text
    )
    assert "The MT9M001 has a two-wire serial interface, not SPI" in text
    # IBIS5: 3.5 us + 1280 / 40 MHz.
    assert "| line period T_line | 35.5 µs |" in text
    assert "| `0x10` " not in text  # addresses are not code-formatted


def test_render_of_one_map(tmp_path: Path) -> None:
    text = render_sensors_doc([load_register_map("ibis5")])
    assert "## 3. ibis5" in text and "## 4." not in text
    assert "| `EXPOSURE` | `EXP_HI`, `EXP_LO` | `GROUP_HOLD.hold` | 1 .. 1048575 | line |" in text


def test_check_mode(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "docs" / "sensors.md"
    assert main(["--check", "--output", str(out)]) == 1
    assert "is missing: run `python -m camd.sensor.docgen`" in capsys.readouterr().err
    assert main(["--output", str(out)]) == 0
    assert out.read_text(encoding="utf-8") == render_sensors_doc(shipped_maps())
    assert main(["--check", "--output", str(out)]) == 0
    assert "is up to date" in capsys.readouterr().out
    out.write_text(out.read_text(encoding="utf-8").replace("20.52 µs", "20.53 µs"))
    assert main(["--check", "--output", str(out)]) == 1
    assert f"{out} is stale: run `python -m camd.sensor.docgen`" in capsys.readouterr().err


def test_bad_map_is_reported(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('sensor = "bad"\n')
    assert main(["--map", str(bad), "--output", str(tmp_path / "s.md")]) == 2
    assert f"docgen: {bad}" in capsys.readouterr().err
    assert not (tmp_path / "s.md").exists()


def test_module_entry_point_checks_the_committed_file() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "camd.sensor.docgen", "--check"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    assert "sensors.md is up to date" in result.stdout
