"""Image motion compensation measurements (docs/physics.md §7; REN15 §3): the clock settings for an
image speed, the sharpness and point-beam modulation of stared frames of a slanted periodic
edge, with the models beside them, and a summary keyed by compensation mode.

The equations live in ``camd.timing.imc`` (image velocity, step intervals, the clocking during
an exposure, the exact point-beam image and the closed-form modulations) and
``camd.analysis`` (``sharpness.grey_gradient_sharpness``, ``imc.edge_line_modulations``,
``imc.periodic_edge_sharpness``); these functions read the data and the recording's metadata
(the exposure, the IMC registers and the pitch the frames were taken with) and call them.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from camd.analysis.imc import edge_line_modulations, periodic_edge_sharpness
from camd.analysis.sharpness import grey_gradient_sharpness
from camd.campaign.measurements import Inputs, Results, measurement, require_input
from camd.timing.imc import (
    IMC_MODES,
    ImcMode,
    electrode_step_interval_s,
    mean_electrode_step_modulation,
    mean_row_step_modulation,
    point_beam_means,
)

MM = 1e-3


@measurement("imc_clocking")
def imc_clocking(inputs: Inputs, *, image_speed_mm_s: float, profile: str) -> Results:
    """Stage speed and IMC step register for an image speed on ``profile``'s camera (§7).

    The electrode-step interval ``dt = w / (p v)`` (``camd.timing.imc``) in clocks of the
    register map's ``timing.clock_hz``, rounded to whole clocks (``imc_step_clocks``, for the
    IMC_STEP register group), with ``p`` from the map's IMC_PHASES register; the stage speed
    that moves the image at ``v`` through the profile's optics, ``v / magnification``
    (``stage_speed_m_s``, REN15's ``V = v H / f``); ``electrode_interval_s`` the interval the
    register gives and ``row_time_ms`` the row-step interval ``w / v``. No inputs.
    """
    from camd.sensor.profile import load_profile
    from camd.sensor.regmap import load_register_map

    speed_m_s = float(image_speed_mm_s) * MM
    if not speed_m_s > 0.0:
        raise ValueError(f"image_speed_mm_s must be > 0, got {image_speed_mm_s}")
    camera = load_profile(profile)
    regmap = load_register_map(camera.sensor)
    if not regmap.has_group("IMC_STEP"):
        raise ValueError(
            f"the {camera.sensor} register map has no IMC_STEP group: image motion "
            "compensation needs a camera that has it (profile ftf5066)"
        )
    phases = int(regmap.value_of("IMC_PHASES", lambda reg: reg.reset))
    pitch_m = camera.pitch_m.value
    dt_s = electrode_step_interval_s(pitch_m, speed_m_s, phases)
    clocks = round(dt_s * regmap.timing.clock_hz)
    return {
        "stage_speed_m_s": speed_m_s / camera.magnification.value,
        "imc_step_clocks": int(clocks),
        "electrode_interval_s": clocks / regmap.timing.clock_hz,
        "row_time_ms": pitch_m / speed_m_s / MM,
    }


def _recorded_imc(metadata: dict[str, dict[str, Any]]) -> tuple[ImcMode, float, int]:
    """(mode, electrode interval s, phases) from a recording's register values."""
    from camd.sensor.regmap import load_register_map

    regmap = load_register_map(str(metadata["timing"]["sensor"]))
    registers = metadata["registers"]
    if not regmap.has_register("IMC_CTRL"):
        return "none", math.inf, 1

    def raw(reg: Any) -> int:
        # IMC_PHASES is read-only (a constant of the sensor), so not in the recorded values.
        return int(registers.get(reg.name, reg.reset))

    mode = regmap.value_of("IMC_CTRL.mode", raw)
    if mode not in IMC_MODES:
        raise ValueError(f"the recording's IMC_CTRL.mode is {mode!r}, not one of {IMC_MODES}")
    interval_s = int(regmap.value_of("IMC_STEP", raw)) / regmap.timing.clock_hz
    return mode, interval_s, int(regmap.value_of("IMC_PHASES", raw))


@measurement("imc_image")
def imc_image(
    inputs: Inputs,
    *,
    image_speed_mm_s: float,
    period_rows: int,
    contrast: float = 1.0,
    black_dn: float = 0.0,
) -> Results:
    """Sharpness and point-beam modulation of stared frames of a slanted periodic edge, and
    their models (docs/physics.md §7, REN15 §3; ``camd.analysis.imc``). Input ``frames``.

    ``image_sharpness``: the grey-gradient function along the track
    (``grey_gradient_sharpness``, axis ``along``, ``black_dn`` removed) averaged over the
    frames; ``sharpness_floor``: the same over the across-track pairs, the noise floor;
    ``image_sharpness_model``: ``periodic_edge_sharpness`` of the exact point-beam profile for this
    speed, exposure and clocking, plus the floor. ``image_modulation``: the mean of
    ``edge_line_modulations`` over every edge of every frame; ``image_modulation_model``: the mean
    over the offset of the exact profile's modulation (``camd.timing.imc.point_beam_means``).
    The exposure, the IMC mode and step interval and the pitch come from the recording
    (``imc_mode``, ``exposure_ms``); the image speed ``image_speed_mm_s`` is what the stage
    was set to give; ``period_rows`` and ``contrast`` describe the target.
    """
    acquired = require_input(inputs, "frames", "imc_image")
    frames = acquired.frames().astype(np.float64)
    metadata = acquired.metadata()
    mode, interval_s, phases = _recorded_imc(metadata)
    exposure_s = float(metadata["timing"]["exposure_s"])
    pitch_m = float(metadata["profile"]["pitch_m"]["value"])
    along = [grey_gradient_sharpness(f, black_dn=black_dn, axis="along") for f in frames]
    across = [grey_gradient_sharpness(f, black_dn=black_dn, axis="across") for f in frames]
    floor = float(np.mean(across))
    modulations = np.concatenate([edge_line_modulations(f, black_dn=black_dn) for f in frames])
    model = point_beam_means(
        pixel_m=pitch_m,
        image_velocity_m_s=float(image_speed_mm_s) * MM,
        exposure_s=exposure_s,
        mode=mode,
        electrode_interval_s=None if mode == "none" else interval_s,
        phases=phases,
    )
    return {
        "imc_mode": mode,
        "exposure_ms": exposure_s / MM,
        "image_sharpness": float(np.mean(along)),
        "sharpness_floor": floor,
        "image_sharpness_model": periodic_edge_sharpness(model.square_sum, period_rows, contrast)
        + floor,
        "image_modulation": float(modulations.mean()),
        "image_modulation_model": model.modulation,
        "edges": int(modulations.size),
    }


def _by_mode(modes: list[list[str]], values: list[list[Any]], what: str) -> dict[str, list[Any]]:
    """A sweep over speeds of a sweep over modes, ``values[speed][mode]``, as {mode: [speeds]}."""
    out: dict[str, list[Any]] = {}
    if len(modes) != len(values):
        raise ValueError(f"{what}: {len(values)} speeds of values but {len(modes)} of modes")
    for speed_modes, speed_values in zip(modes, values, strict=True):
        if len(speed_modes) != len(speed_values):
            raise ValueError(f"{what}: modes {speed_modes} do not match values {speed_values}")
        for mode, value in zip(speed_modes, speed_values, strict=True):
            out.setdefault(str(mode), []).append(value)
    return {m: out[m] for m in IMC_MODES if m in out}


@measurement("imc_summary")
def imc_summary(
    inputs: Inputs,
    *,
    speed_mm_s: list[float],
    imc_mode: list[list[str]],
    image_sharpness: list[list[float]],
    image_sharpness_model: list[list[float]],
    image_modulation: list[list[float]],
    image_modulation_model: list[list[float]],
    one_row_speed_mm_s: float,
) -> Results:
    """The per-image results (``imc_image``) of a sweep over image speed and, inside it, IMC
    mode, keyed by mode, with the comparisons a report checks (docs/physics.md §7, REN15 §3). No inputs.

    ``sharpness``, ``sharpness_model``, ``modulation``, ``modulation_model``: ``{mode: [one per
    speed]}``. ``sharpness_error``: ``{mode: [measured / model - 1]}``. ``sharpness_ratio``:
    ``{"electrode_over_row": [...], "row_over_none": [...]}`` per speed.
    ``modulation_mean``: ``{"row": x, "electrode": x}`` measured at ``one_row_speed_mm_s``, the
    speed at which the exposure is one row time ``w / v``, where the mean over the offset of
    the closed forms is exact: ``modulation_closed_form`` (1/3 and 47/96) and
    ``modulation_mean_error`` (measured minus closed form) beside it.
    ``sharpness_gain_fast``: ``{"electrode_over_row": [...], "electrode_over_none": [...]}`` at
    the speeds from ``one_row_speed_mm_s`` up, where the image moves at least a pixel in the
    exposure and electrode steps must show.
    """
    speeds = [float(s) for s in speed_mm_s]
    sharp = _by_mode(imc_mode, image_sharpness, "image_sharpness")
    sharp_model = _by_mode(imc_mode, image_sharpness_model, "image_sharpness_model")
    mod = _by_mode(imc_mode, image_modulation, "image_modulation")
    mod_model = _by_mode(imc_mode, image_modulation_model, "image_modulation_model")
    for mode, values in sharp.items():
        if len(values) != len(speeds):
            raise ValueError(f"mode {mode}: {len(values)} images for {len(speeds)} speeds")
    missing = [m for m in IMC_MODES if m not in sharp]
    if missing:
        raise ValueError(f"no images with IMC mode {', '.join(missing)}: sweep all three modes")
    matches = [i for i, s in enumerate(speeds) if math.isclose(s, float(one_row_speed_mm_s))]
    if not matches:
        raise ValueError(
            f"one_row_speed_mm_s = {one_row_speed_mm_s} is not among the speeds {speeds}"
        )
    at = matches[0]
    fast = [i for i, s in enumerate(speeds) if s >= speeds[at]]
    closed = {
        "row": mean_row_step_modulation(),
        "electrode": mean_electrode_step_modulation(),
    }
    mean = {mode: mod[mode][at] for mode in closed}
    return {
        "sharpness": sharp,
        "sharpness_model": sharp_model,
        "sharpness_error": {
            m: [x / y - 1.0 for x, y in zip(sharp[m], sharp_model[m], strict=True)] for m in sharp
        },
        "sharpness_ratio": {
            "electrode_over_row": [
                e / r for e, r in zip(sharp["electrode"], sharp["row"], strict=True)
            ],
            "row_over_none": [r / n for r, n in zip(sharp["row"], sharp["none"], strict=True)],
        },
        "sharpness_gain_fast": {
            "electrode_over_row": [sharp["electrode"][i] / sharp["row"][i] for i in fast],
            "electrode_over_none": [sharp["electrode"][i] / sharp["none"][i] for i in fast],
        },
        "modulation": mod,
        "modulation_model": mod_model,
        "modulation_mean": mean,
        "modulation_closed_form": closed,
        "modulation_mean_error": {mode: mean[mode] - closed[mode] for mode in closed},
    }
