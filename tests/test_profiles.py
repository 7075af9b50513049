"""Camera profiles: every value has a provenance, bad files name the key, numbers hand-checked."""

from __future__ import annotations

import math
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from camd.sensor.profile import (
    CameraProfile,
    ProfileError,
    list_profiles,
    load_profile,
)
from camd.sensor.profile_docs import main, render_profiles_doc, shipped_profiles
from camd.sensor.regmap import load_register_map
from camd.sensor.timing_view import reset_timing

ROOT = Path(__file__).resolve().parents[1]
PROFILES = ROOT / "config" / "profiles"
PROFILES_MD = ROOT / "docs" / "profiles.md"
NAMES = ["ftf5066", "hr400", "ibis5", "mt9m001", "uvccd"]


def test_the_five_profiles_ship_and_load() -> None:
    assert set(NAMES) <= set(list_profiles())
    for name in NAMES:
        profile = load_profile(name)
        assert profile.profile == name
        assert profile.sensor == name  # each camera's sensor carries the map of that name
        assert load_profile(PROFILES / f"{name}.toml") == profile


@pytest.mark.parametrize("name", NAMES)
def test_every_physical_value_is_an_inline_table_with_source_xor_assumed(name: str) -> None:
    raw = tomllib.loads((PROFILES / f"{name}.toml").read_text(encoding="utf-8"))
    keys = CameraProfile.physical_keys()
    assert len(keys) == 22
    for key in keys:
        entry = raw[key]
        assert isinstance(entry, dict), key
        assert set(entry) in ({"value", "source"}, {"value", "assumed"}), (key, entry)
        assert entry.get("source", entry.get("assumed", "")).strip(), key
    gain = raw["analog_gain"]
    assert ("source" in gain) != ("assumed" in gain)


@pytest.mark.parametrize("name", NAMES)
def test_profile_line_period_agrees_with_the_register_map(name: str) -> None:
    """docs/physics.md §2 eq 4 from the profile's values = the map's timing at reset."""
    profile = load_profile(name)
    timing = reset_timing(load_register_map(name))
    assert profile.line_period_s() == pytest.approx(timing.line_period_s, rel=1e-9)


def test_system_gain_against_hand_computation() -> None:
    # K = g_conv * G / (V_FS / 2^bits)
    hr400 = load_profile("hr400")
    assert hr400.system_gain_dn_per_e() == pytest.approx(10e-6 * 4096 / 1.0, rel=1e-12)
    assert hr400.system_gain_dn_per_e() == pytest.approx(0.04096, rel=1e-12)
    assert hr400.analog_gain_factor("x4") == 4.0
    assert hr400.system_gain_dn_per_e(hr400.analog_gain_factor("x2")) == pytest.approx(0.08192)
    ibis5 = load_profile("ibis5")
    assert ibis5.system_gain_dn_per_e() == pytest.approx(14e-6 * 1024, rel=1e-12)
    assert ibis5.output_shift_bits == 2 and ibis5.adc_max_dn == 1023
    uvccd = load_profile("uvccd")
    assert uvccd.system_gain_dn_per_e() == pytest.approx(10e-6 * 16384 / 2.0, rel=1e-12)
    assert uvccd.analog_gain_factor(12) == pytest.approx(10 ** (6.0 / 20.0))  # 12 x 0.5 dB
    mt9m001 = load_profile("mt9m001")
    # Datasheet coding: 0x08..0x20 = code / 8, bit 6 doubles, 0x61..0x67 = 9..15.
    codes = {0x08: 1.0, 0x0C: 1.5, 0x20: 4.0, 0x51: 4.25, 0x60: 8.0, 0x61: 9.0, 0x67: 15.0}
    for code, factor in codes.items():
        assert mt9m001.analog_gain_factor(code) == pytest.approx(factor), hex(code)
    assert mt9m001.system_gain_dn_per_e(8.0) == pytest.approx(30e-6 * 8 * 1024)
    with pytest.raises(ValueError, match="no factor"):
        hr400.analog_gain_factor("x3")


def test_paper_values_are_respected() -> None:
    hr400 = load_profile("hr400")
    assert hr400.read_noise_e.value == 37.2 and hr400.adc_bits.value == 12
    assert hr400.pitch_m.value == 11e-6
    ibis5 = load_profile("ibis5")
    assert (ibis5.adc_bits.value, ibis5.output_bits.value) == (10, 8)
    assert ibis5.row_blanking_s.value == 3.5e-6
    # 7.22 mV/s converted with the (assumed) conversion gain.
    volts_per_e = ibis5.conversion_gain_uv_per_e.value * 1e-6
    assert ibis5.dark_current_e_per_s.value == pytest.approx(7.22e-3 / volts_per_e, abs=0.05)
    mt9m001 = load_profile("mt9m001")
    assert mt9m001.pitch_m.value == 5.2e-6 and mt9m001.pixel_rate_hz.value == 48e6
    assert mt9m001.adc_bits.value == 10
    uvccd = load_profile("uvccd")
    assert (uvccd.columns.value, uvccd.rows.value) == (600, 500)
    assert uvccd.pitch_m.value == 14e-6 and uvccd.adc_bits.value == 14
    assert uvccd.adc_full_scale_v.value == 2.0 and uvccd.shutter.value == "frame_transfer"
    assert uvccd.pixel_rate_hz.value == 6.6e6


def test_uvccd_dark_noise_is_5_4_lsb() -> None:
    """DONG16: staring-mode temporal dark noise 5.4 LSB (0.66 mV) at the reset settings."""
    p = load_profile("uvccd")
    timing = reset_timing(load_register_map("uvccd"))
    k = p.system_gain_dn_per_e(p.analog_gain_factor(timing.gain))
    dark_e = p.dark_current_e_per_s.value * timing.exposure_s
    noise_lsb = math.sqrt(k**2 * (p.read_noise_e.value**2 + dark_e) + 1 / 12)
    assert noise_lsb == pytest.approx(5.4, abs=0.01)
    lsb_v = p.adc_full_scale_v.value / 2**p.adc_bits.value
    assert noise_lsb * lsb_v == pytest.approx(0.66e-3, abs=0.005e-3)


# -- bad files -----------------------------------------------------------------------------------


def corrupt(tmp_path: Path, old: str, new: str, name: str = "hr400") -> tuple[Path, int]:
    """A copy of a shipped profile with one text replaced; returns the path and that line."""
    text = (PROFILES / f"{name}.toml").read_text(encoding="utf-8")
    assert old in text, old
    line = text[: text.index(old)].count("\n") + 1
    path = tmp_path / f"{name}.toml"
    path.write_text(text.replace(old, new, 1), encoding="utf-8")
    return path, line


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        (
            'pitch_m = { value = 11e-6, source = "YE23 §3.2 / docs/physics.md §3, §8" }',
            'pitch_m = { value = 11e-6, source = "YE23", assumed = "guess" }',
            "pitch_m: give exactly one of `source` (where the value comes from) or `assumed` "
            "(why it was chosen), not both",
        ),
        (
            'pitch_m = { value = 11e-6, source = "YE23 §3.2 / docs/physics.md §3, §8" }',
            "pitch_m = { value = 11e-6 }",
            "pitch_m: give exactly one of `source`",
        ),
        (
            'pitch_m = { value = 11e-6, source = "YE23 §3.2 / docs/physics.md §3, §8" }',
            "pitch_m = 11e-6",
            "pitch_m: Input should be a valid dictionary or instance of Sourced",
        ),
        (
            "pitch_m = { value = 11e-6,",
            "pitch_m = { value = -11e-6,",
            "pitch_m.value: -1.1e-05 is out of range; allowed: 0 < value",
        ),
        (
            'shutter = { value = "rolling",',
            'shutter = { value = "rollin",',
            "shutter.value: 'rollin' is not allowed; use 'rolling', 'global', 'frame_transfer' or "
            "'full_frame'",
        ),
        (
            "pitch_m = { value = 11e-6,",
            "pitch_m = { value = 11e-6, unit = 'm',",
            "pitch_m.unit: unknown key; known keys: value, source, assumed",
        ),
        (
            "output_bits = { value = 12,",
            "output_bits = { value = 14,",
            "output_bits: output_bits 14 exceeds adc_bits 12",
        ),
        (
            "columns = { value = 2048,",
            "columns = { value = 2000,",
            "columns: 2000 differs from the hr400 register map's columns = 2048; make them agree",
        ),
        (
            "table = { x1 = 1.0, x2 = 2.0, x4 = 4.0, x8 = 8.0 }",
            "table = { x1 = 1.0, x2 = 2.0, x4 = 4.0 }",
            "analog_gain: no factor for gain label(s) x8 of the hr400 register map; add them",
        ),
        (
            'sensor = "hr400"',
            'sensor = "nosuch"',
            "sensor: no register map for sensor 'nosuch'",
        ),
    ],
)
def test_bad_profile_names_file_line_and_key(
    tmp_path: Path, old: str, new: str, message: str
) -> None:
    path, line = corrupt(tmp_path, old, new)
    with pytest.raises(ProfileError) as info:
        load_profile(path)
    assert str(info.value).startswith(f"{path}:{line}: "), str(info.value)
    assert message in str(info.value)


def test_missing_and_unknown_keys(tmp_path: Path) -> None:
    path, line = corrupt(tmp_path, "magnification = {", "magnifcation = {")
    with pytest.raises(ProfileError) as info:
        load_profile(path)
    # The first problem pydantic reports: either the missing key or the misspelt one.
    text = str(info.value)
    assert "magnification: missing key; add `magnification = { value = ..., source" in text or (
        f"{path}:{line}: magnifcation: unknown key" in text
    )


def test_db_gain_must_match_the_map_field(tmp_path: Path) -> None:
    path, line = corrupt(tmp_path, "db_per_code = 0.5", "db_per_code = 0.25", name="uvccd")
    with pytest.raises(ProfileError) as info:
        load_profile(path)
    assert str(info.value).startswith(f"{path}:{line}: analog_gain: db_per_code = 0.25 but the")


def test_bad_toml_and_unknown_names(tmp_path: Path) -> None:
    path, line = corrupt(tmp_path, "rows = { value = 2048", "rows = = { value = 2048")
    with pytest.raises(ProfileError, match=rf"^{path}:{line}: "):
        load_profile(path)
    with pytest.raises(FileNotFoundError, match=r"known: ftf5066, hr400, ibis5, mt9m001, uvccd"):
        load_profile("nosuch")
    with pytest.raises(ProfileError, match="not a camera profile name"):
        load_profile("../etc/passwd")


# -- the uvccd register map the simulator needs ---------------------------------------------------


def test_uvccd_register_map_has_the_timing_roles() -> None:
    regmap = load_register_map("uvccd")
    assert regmap.modelled is True and (regmap.rows, regmap.columns) == (500, 600)
    timing = reset_timing(regmap)
    assert timing.line_period_s == pytest.approx(10e-6 + 600 / 6.6e6, rel=1e-12)
    assert (timing.window_start_row, timing.window_rows) == (0, 500)
    assert timing.exposure_s == pytest.approx(100 * timing.line_period_s)
    assert (timing.gain, timing.offset, timing.test_pattern) == (0, 200, "off")


# -- docs ---------------------------------------------------------------------------------------


def test_profiles_md_is_current() -> None:
    assert PROFILES_MD.read_text(encoding="utf-8") == render_profiles_doc(shipped_profiles()), (
        "docs/profiles.md is stale: run `python -m camd.sensor.profile_docs`"
    )


def test_profiles_md_lists_every_key_value_and_provenance() -> None:
    text = render_profiles_doc(shipped_profiles())
    for profile in shipped_profiles():
        for key in CameraProfile.physical_keys():
            entry = profile.sourced(key)
            assert f"| `{key}` |" in text
            assert (entry.source or entry.assumed or "") in text
    assert "| system gain K | 0.04096 DN/e- (24.4141 e-/DN) |" in text
    assert "| dark noise without dark charge, sqrt((sigma K)^2 + 1/12) | 5.4 DN |" in text
    assert "960 DN (ADC), 240 DN at the 8-bit output" in text


def test_docs_check_mode(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "profiles.md"
    assert main(["--check", "--output", str(out)]) == 1
    assert "is missing: run `python -m camd.sensor.profile_docs`" in capsys.readouterr().err
    assert main(["--output", str(out)]) == 0
    assert main(["--check", "--output", str(out)]) == 0
    out.write_text(out.read_text(encoding="utf-8").replace("0.04096", "0.04097"))
    assert main(["--check", "--output", str(out)]) == 1


def test_module_entry_point_checks_the_committed_file() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "camd.sensor.profile_docs", "--check"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    assert "profiles.md is up to date" in result.stdout
