"""Generate docs/profiles.md from the camera-profile schema and the shipped profiles.

The document lists every key of ``camd.sensor.profile.CameraProfile`` with its unit and
meaning, then every shipped profile (``config/profiles/*.toml``) key by key with its value and
its source or assumption, and the numbers that follow from them (system gain, full well and
read noise in DN), so it cannot drift from the files; ``tests/test_profiles.py`` fails when the
committed file is stale.

    python -m camd.sensor.profile_docs            write docs/profiles.md
    python -m camd.sensor.profile_docs --check    exit 1 if docs/profiles.md differs
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence

from camd.markdown import docgen_parser, table, write_or_check
from camd.sensor.profile import (
    CameraProfile,
    GainSpec,
    ProfileError,
    list_profiles,
    load_profile,
)
from camd.sensor.regmap import RegisterMapError, load_register_map
from camd.sensor.timing_view import reset_timing

COMMAND = "python -m camd.sensor.profile_docs"


def _num(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.10g}"
    return str(value)


def _schema() -> list[str]:
    rows = []
    for key in CameraProfile.physical_keys():
        info = CameraProfile.model_fields[key]
        rows.append([f"`{key}`", CameraProfile.unit_of(key) or "", info.description or ""])
    gain_rows = [
        [f"`{name}`", info.description or ""] for name, info in GainSpec.model_fields.items()
    ]
    return [
        "## 1. Profile schema",
        "",
        "A camera profile is one TOML file, `config/profiles/<name>.toml`, loaded and validated by "
        "`camd.sensor.profile.load_profile` (pydantic; unknown keys are errors). Top-level "
        "`profile` (the name), `description` and `sensor` (the register map in "
        "`config/sensors/`, which the simulated camera's sensor carries) are plain strings. "
        "Every physical value is an inline table with its provenance, exactly one of `source` "
        "(where the number comes from) or `assumed` (why it was chosen):",
        "",
        '    pitch_m = { value = 11e-6, source = "YE23 §3.2 / docs/physics.md §3, §8" }',
        '    fill_factor = { value = 0.8, assumed = "sCMOS pixel with microlenses; no paper '
        'gives it" }',
        "",
        *table(["Key", "Unit", "Meaning"], rows),
        "",
        "### `[analog_gain]`: the gain register as an analogue gain factor",
        "",
        "The sensor's gain role (`SensorModel.gain`: an enum label such as `x2`, or a raw code) "
        "maps to a factor `G`:",
        "",
        "- `table`: label -> factor; every label of the register map's gain enum needs one.",
        "- `code`: `G = (code mod 2^double_bit) / divisor`, doubled when bit `double_bit` is set; "
        '`table` entries (keys such as `"0x61"`) override single codes.',
        "- `db`: `G = 10^((db_at_zero + db_per_code * code) / 20)`; when the map's gain field is "
        "in dB its scale must equal `db_per_code`.",
        "",
        *table(["Key", "Meaning"], gain_rows),
        "",
        "### Derived quantities",
        "",
        "- System gain (docs/physics.md §5): `K = conversion_gain * G / (adc_full_scale_v / "
        "2^adc_bits)` in ADC DN per electron (`CameraProfile.system_gain_dn_per_e`).",
        "- Black level: `black_level_dn + offset_dn_per_code * offset` in ADC DN, `offset` the "
        "sensor's offset role (`CameraProfile.black_level_for`).",
        "- Dark current at temperature `T`: `dark_current_e_per_s * 2^((T - "
        "dark_reference_temp_degc) / dark_doubling_temp_degc)`; the DSNU map scales with it.",
        "- Aperture: a centred square of side `q = sqrt(fill_factor)` pitches "
        "(`CameraProfile.aperture`); a flat field of `L` photons/pixel/s at the focal plane "
        "gives `QE * fill_factor * L * T` electrons.",
        "- Output: the ADC's `output_bits` most significant bits.",
        "- Line period from the profile's values: `T_line = row_blanking_s + columns / "
        "pixel_rate_hz` (docs/physics.md §2 eq 4); the simulated sensor's timing comes from its "
        "register map, and `tests/test_profiles.py` checks that the two agree at the reset "
        "values.",
        "",
        "### Load errors",
        "",
        "A profile that breaks a rule is refused with `ProfileError`, whose message starts with "
        "`file:line:` and names the key, e.g. `config/profiles/hr400.toml:17: pitch_m: give "
        "exactly one of `source` ... or `assumed` ..., not both`. Checked: TOML syntax; unknown "
        "and missing keys; types and bounds; exactly one provenance per value; `output_bits <= "
        "adc_bits`; the register map `sensor` exists and has the same rows and columns; the gain "
        "coding fits the map's gain field (a factor for every enum label; a number field needs "
        "`code` or `db`).",
        "",
    ]


def _gain_text(gain: GainSpec) -> str:
    if gain.kind == "table":
        pairs = ", ".join(f"`{k}` = {_num(v)}" for k, v in gain.table.items())
        return f"table: {pairs}"
    if gain.kind == "code":
        text = f"code: G = (code mod 2^{gain.double_bit}) / {_num(gain.divisor)}"
        if gain.double_bit is not None:
            text += f", x2 when bit {gain.double_bit} is set"
        else:
            text = f"code: G = code / {_num(gain.divisor)}"
        if gain.table:
            text += "; " + ", ".join(f"{k} = {_num(v)}" for k, v in gain.table.items())
        return text
    return f"db: G = 10^(({_num(gain.db_at_zero)} + {_num(gain.db_per_code)} * code) / 20)"


def _profile(number: int, profile: CameraProfile) -> list[str]:
    rows = []
    for key in CameraProfile.physical_keys():
        entry = profile.sourced(key)
        kind = "source" if entry.source else "**assumed**"
        text = entry.source if entry.source else entry.assumed
        rows.append(
            [f"`{key}`", _num(entry.value), CameraProfile.unit_of(key) or "", f"{kind}: {text}"]
        )
    gain_kind = "source" if profile.analog_gain.source else "**assumed**"
    gain_note = profile.analog_gain.source or profile.analog_gain.assumed or ""
    rows.append(["`analog_gain`", _gain_text(profile.analog_gain), "", f"{gain_kind}: {gain_note}"])
    regmap = load_register_map(profile.sensor)
    timing = reset_timing(regmap)
    gain = profile.analog_gain_factor(timing.gain)
    k_dn = profile.system_gain_dn_per_e(gain)
    black = profile.black_level_for(timing.offset)
    full_well_dn = profile.full_well_e.value * k_dn
    read_dn = profile.read_noise_e.value * k_dn
    dark_noise_dn = math.sqrt(read_dn**2 + 1.0 / 12.0)
    saturation = min(full_well_dn + black, profile.adc_max_dn)
    derived = [
        ["analogue gain G at the reset gain setting", f"{_num(gain)} (`{timing.gain}`)"],
        ["system gain K", f"{k_dn:.6g} DN/e- ({1 / k_dn:.6g} e-/DN)"],
        ["black level at the reset offset", f"{black:.6g} DN"],
        ["full well", f"{full_well_dn:.6g} DN above the black level"],
        ["saturation code min(FW K + B, 2^adc_bits - 1)", f"{saturation:.6g} DN (ADC)"
         + (f", {saturation / 2**profile.output_shift_bits:.6g} DN at the {profile.output_bits.value}-bit output"
            if profile.output_shift_bits else "")],
        ["read noise", f"{read_dn:.4g} DN"],
        ["dark noise without dark charge, sqrt((sigma K)^2 + 1/12)", f"{dark_noise_dn:.4g} DN"],
        ["aperture q = sqrt(fill_factor)", f"{profile.aperture:.6g} pitch"],
        ["line period from the profile (row_blanking_s + columns / pixel_rate_hz)",
         f"{profile.line_period_s() * 1e6:.6g} µs"],
        ["line period from the register map at reset", f"{timing.line_period_s * 1e6:.6g} µs"],
    ]  # fmt: skip
    assumed = sum(1 for key in CameraProfile.physical_keys() if profile.sourced(key).is_assumed)
    return [
        f"## {number}. {profile.profile}",
        "",
        f"{profile.description}. Register map: `config/sensors/{profile.sensor}.toml`. File: "
        f"`config/profiles/{profile.profile}.toml`. {assumed} of "
        f"{len(CameraProfile.physical_keys())} values are assumptions.",
        "",
        *table(["Key", "Value", "Unit", "Provenance"], rows),
        "",
        "Derived at the register reset values:",
        "",
        *table(["Quantity", "Value"], derived),
        "",
    ]


def render_profiles_doc(profiles: Sequence[CameraProfile]) -> str:
    """Return the full text of docs/profiles.md for ``profiles``."""
    contents = ["1. Profile schema"] + [
        f"{i}. {p.profile}" for i, p in enumerate(profiles, start=2)
    ]
    lines = [
        "# Camera profiles",
        "",
        f"<!-- Generated by `{COMMAND}`; do not edit by hand. -->",
        "",
        "A camera profile holds the physical facts the simulated camera (`firmware_models."
        "camera`) needs about one camera (docs/physics.md §8), each with its source or the "
        "assumption behind it. This document is generated from the schema "
        f"(`camd/sensor/profile.py`) and the shipped profiles by `{COMMAND}`; "
        "`tests/test_profiles.py` fails when it differs, so edit the profiles and regenerate.",
        "",
        *contents,
        "",
        *_schema(),
    ]
    for number, profile in enumerate(profiles, start=2):
        lines += _profile(number, profile)
    return "\n".join(lines).rstrip("\n") + "\n"


def shipped_profiles() -> list[CameraProfile]:
    """Every profile in config/profiles/, by name."""
    return [load_profile(name) for name in list_profiles()]


def main(argv: Sequence[str] | None = None) -> int:
    parser = docgen_parser(
        COMMAND,
        "Generate docs/profiles.md from the profile schema and the shipped profiles.",
        "profiles.md",
    )
    args = parser.parse_args(argv)
    try:
        text = render_profiles_doc(shipped_profiles())
    except (ProfileError, RegisterMapError, FileNotFoundError) as exc:
        print(f"profile_docs: {exc}", file=sys.stderr)
        return 2
    return write_or_check(args.output, text, check=args.check, command=COMMAND)


if __name__ == "__main__":
    raise SystemExit(main())
