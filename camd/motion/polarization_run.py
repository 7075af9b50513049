"""The polarisation azimuth measurement through the filter wheel, driven over the camd API.

physics.md §4 [YE23 §4]: a reference polariser in front of the scene is rotated through 0 .. 360
deg (15 deg steps); at each position one frame is taken through each polarising channel of the
wheel, and the frames' mean signals follow ``I(theta) = a + b cos(2 (theta - phi))``; the
least-squares fit (``camd.analysis.polarization.fit_polarization``) gives each channel's
azimuth ``phi``. Without delay compensation the frame's centre, and with it the polariser in
the wheel, sits ``w (T_frame / 2 - T_center)`` from the channel centre, so the azimuth moves
with the exposure; with compensation it does not. ``measure_polarization_azimuth`` runs that
for several exposures with and without compensation and reports the azimuths and their spread
across the exposures.

It talks to the daemon only through ``camd.client.CamdClient`` (``set_polarizer``,
``wheel_acquire``, ``wheel``, ``set_wheel_compensation``), so a campaign or a script can run it
against any daemon whose camera has a reference polariser (the simulated one:
PUT /api/v1/sim/polarizer). Seconds and degrees in code; the result also gives milliseconds
for the exposures because that is how they are quoted.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from camd.analysis.polarization import azimuth_spread_deg, fit_polarization

if TYPE_CHECKING:
    from camd.client import CamdClient

DEFAULT_EXPOSURES_S = (0.003, 0.015, 0.060)
"""The exposures of issue 6: 3, 15 and 60 ms."""

DEFAULT_STEP_DEG = 15.0
"""Reference polariser step (physics.md §4: 0 .. 360 deg in 15 deg steps)."""

SETTINGS = (("compensated", True), ("uncompensated", False))

Progress = Callable[[int, int, str], None]
"""``progress(done, total, what)`` after each acquisition."""


def reference_angles_deg(step_deg: float) -> list[float]:
    """Reference polariser positions 0, step, ... below 360 deg (360 would repeat 0)."""
    if not (math.isfinite(step_deg) and 0.0 < step_deg <= 60.0):
        raise ValueError(
            f"the reference polariser step must be > 0 and <= 60 deg (at least 3 distinct "
            f"positions modulo 180 deg for the fit), got {step_deg:g}"
        )
    count = math.ceil(360.0 / step_deg - 1e-9)
    return [round(i * step_deg, 9) for i in range(count)]


def measure_polarization_azimuth(
    client: CamdClient,
    *,
    channels: Sequence[int] | None = None,
    exposures_s: Sequence[float] = DEFAULT_EXPOSURES_S,
    step_deg: float = DEFAULT_STEP_DEG,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Azimuth of each polarising channel per exposure, with and without delay compensation.

    ``channels``: polarising channels (default: all of the wheel's). For each compensation
    setting, each exposure and each reference angle the polariser is set and one pass through
    the channels is taken; each channel's frame means are then fitted. Returns::

        {"channels": [...], "reference_deg": [...], "exposure_ms": [...],
         "exposure_s": [...], "frame_time_s": [...],          # as the registers set them
         "azimuth_deg": {"compensated": {"10": [...], ...}, "uncompensated": {...}},
         "azimuth_error_deg": {...}, "shift_deg": {...},      # azimuth - the polariser's axis
         "predicted_shift_deg": {"compensated": [...], "uncompensated": [...]},
         "spread_deg": {"compensated": x, "uncompensated": x},
         "spread_by_channel_deg": {...}, "predicted_spread_deg": {...}}

    ``spread_deg`` is, per setting, the largest over the channels of the spread of a channel's
    azimuths across the exposures (``azimuth_spread_deg``); ``predicted_*`` come from the
    daemon's eq-4 centre offsets. The polariser is taken out and the wheel's compensation
    setting restored afterwards (the exposure stays at the last one). ValueError for channels
    without a polariser or bad exposures; the client's CamdError for anything the daemon
    refuses.
    """
    angles = reference_angles_deg(step_deg)
    exposures = [float(e) for e in exposures_s]
    if not exposures or any(not (math.isfinite(e) and e > 0.0) for e in exposures):
        raise ValueError(f"give one or more exposures > 0 s, got {list(exposures_s)}")
    wheel = client.wheel()
    axes = {c["channel"]: c["polarizer_deg"] for c in wheel["channels"]}
    polarizing = [c for c, axis in axes.items() if axis is not None]
    chosen = list(polarizing if channels is None else channels)
    listed = ", ".join(map(str, polarizing))
    if not chosen:
        raise ValueError(f"choose at least one polarising channel ({listed})")
    unknown = [c for c in chosen if c not in axes]
    if unknown:
        raise ValueError(
            f"channel(s) {', '.join(map(str, unknown))} do not exist; the wheel has channels "
            f"0 .. {len(axes) - 1} and the polarising ones are {listed}"
        )
    plain = [c for c in chosen if axes[c] is None]
    if plain:
        raise ValueError(
            f"channel(s) {', '.join(map(str, plain))} carry no polariser, so they have no "
            f"azimuth; the polarising channels are {listed}"
        )
    keys = [str(c) for c in chosen]
    was_compensated = wheel["compensation"]
    total = len(SETTINGS) * len(exposures) * len(angles)
    done = 0

    result: dict[str, Any] = {
        "channels": chosen,
        "reference_deg": angles,
        "exposure_ms": [e * 1e3 for e in exposures],
        "exposure_s": [],
        "frame_time_s": [],
        "azimuth_deg": {},
        "azimuth_error_deg": {},
        "shift_deg": {},
        "predicted_shift_deg": {},
        "spread_deg": {},
        "spread_by_channel_deg": {},
        "predicted_spread_deg": {},
    }

    def restore() -> None:
        client.set_polarizer(None)
        if client.wheel()["compensation"] != was_compensated:
            client.set_wheel_compensation(was_compensated)

    try:
        for name, compensated in SETTINGS:
            azimuths: dict[str, list[float]] = {k: [] for k in keys}
            errors: dict[str, list[float]] = {k: [] for k in keys}
            predicted: list[float] = []
            for exposure_s in exposures:
                means: dict[str, list[float]] = {k: [] for k in keys}
                exposure_doc = None
                for angle in angles:
                    client.set_polarizer(angle)
                    doc = client.wheel_acquire(
                        chosen, exposure_s=exposure_s, compensated=compensated
                    )
                    exposure_doc = doc["exposure"]
                    got = {str(f["channel"]): f["mean"] for f in doc["frames"]}
                    missing = [k for k in keys if k not in got]
                    if missing:
                        raise RuntimeError(
                            f"the frame(s) of channel(s) {', '.join(missing)} were lost at "
                            f"{angle:g} deg ({exposure_s * 1e3:g} ms, {name}); see `camctl "
                            "events` and repeat"
                        )
                    for k in keys:
                        means[k].append(got[k])
                    done += 1
                    if progress is not None:
                        progress(done, total, f"{name} {exposure_s * 1e3:g} ms, {angle:g} deg")
                assert exposure_doc is not None  # angles is never empty
                if compensated:  # the same registers either way: record them once
                    result["exposure_s"].append(exposure_doc["exposure_s"])
                    result["frame_time_s"].append(exposure_doc["frame_time_s"])
                predicted.append(float(exposure_doc["centre_offset_deg"] or 0.0))
                for k in keys:
                    fit = fit_polarization(angles, means[k])
                    azimuths[k].append(fit.azimuth_deg)
                    errors[k].append(fit.azimuth_error_deg)
            by_channel = {k: azimuth_spread_deg(azimuths[k]) for k in keys}
            result["azimuth_deg"][name] = azimuths
            result["azimuth_error_deg"][name] = errors
            result["shift_deg"][name] = {
                k: [_fold90(a - float(axes[int(k)] or 0.0)) for a in azimuths[k]] for k in keys
            }
            result["predicted_shift_deg"][name] = predicted
            result["spread_by_channel_deg"][name] = by_channel
            result["spread_deg"][name] = max(by_channel.values())
            result["predicted_spread_deg"][name] = float(np.ptp(predicted))
    except BaseException:
        # Leave the polariser out and the setting as found, without hiding the first error.
        with contextlib.suppress(Exception):
            restore()
        raise
    restore()
    return result


def _fold90(angle_deg: float) -> float:
    """An axial angle difference folded into [-90, 90)."""
    return (angle_deg + 90.0) % 180.0 - 90.0
