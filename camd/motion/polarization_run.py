"""The polarisation azimuth measurement through the filter wheel, driven over the camd API.

docs/physics.md §4 [YE23 §4]: a reference polariser in front of the scene is rotated through 0 .. 360
deg (15 deg steps); at each position one frame is taken through each polarising channel of the
wheel, and the frames' mean signals follow ``I(theta) = a + b cos(2 (theta - phi))``; the
least-squares fit (``camd.analysis.polarization.fit_polarization``) gives each channel's
azimuth ``phi``. Without delay compensation the frame's centre, and with it the polariser in
the wheel, sits ``w (T_frame / 2 - T_center)`` from the channel centre, so the azimuth moves
with the exposure; with compensation it does not.

Two halves, so that a script, ``camctl wheel azimuth`` and a campaign share them:

- ``acquire_polarization`` takes the frames (for each compensation setting, exposure and
  reference angle one pass through the channels) and returns a ``PolarizationScan``: the
  frame means and the exposure each setting ran with;
- ``fit_polarization_scan`` fits each channel's azimuth per setting and exposure and reports
  the azimuths, their spread across the exposures and the eq-4 prediction.

``measure_polarization_azimuth`` is the two in a row. ``write_polarization_scan`` and
``read_polarization_scan`` keep a scan in HDF5 (a campaign's raw data).

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
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

import numpy as np
import numpy.typing as npt

from camd.analysis.polarization import (
    axial_difference_deg,
    azimuth_spread_deg,
    fit_polarization,
)

if TYPE_CHECKING:
    from camd.client import CamdClient

DEFAULT_EXPOSURES_S = (0.003, 0.015, 0.060)
"""The exposures of issue 6: 3, 15 and 60 ms."""

DEFAULT_STEP_DEG = 15.0
"""Reference polariser step (docs/physics.md §4: 0 .. 360 deg in 15 deg steps)."""

SETTINGS = (("compensated", True), ("uncompensated", False))

SCAN_FORMAT: Final = "camd-polarization-scan"
SCAN_FORMAT_VERSION: Final = 1

EXPOSURE_KEYS: Final = (
    "exposure_s",
    "exposure_lines",
    "window_rows",
    "line_period_s",
    "frame_time_s",
    "applied_delay_s",
    "centre_offset_deg",
    "centre_error_deg",
)
"""What a scan keeps of each acquisition's exposure document (docs/api.md, the wheel)."""

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


@dataclass(frozen=True)
class PolarizationScan:
    """Frame means of a reference-polariser scan through the wheel's polarising channels.

    ``means[s, e, a, c]`` (DN, the whole frame's mean) is the frame of channel
    ``channels[c]`` with the reference polariser at ``reference_deg[a]``, exposure
    ``exposures_s[e]`` (as asked; the registers' whole lines are in ``exposure``) and
    compensation setting ``settings[s]`` ("compensated" or "uncompensated").
    ``header_centre_deg`` (same shape) is each frame's imaging centre from its header angle
    (start angle + w T_frame / 2). ``exposure[s][e]`` holds the acquisition's exposure
    document (``EXPOSURE_KEYS``: the lines, T_frame, the delay applied, camd's eq-4 centre
    offset and eq-8 uncertainty). ``polarizer_deg[c]`` is each channel's polariser axis and
    ``speed_deg_s`` the wheel's speed.
    """

    channels: list[int]
    polarizer_deg: list[float]
    reference_deg: list[float]
    exposures_s: list[float]
    settings: list[str]
    means: npt.NDArray[np.float64]
    header_centre_deg: npt.NDArray[np.float64]
    exposure: list[list[dict[str, Any]]]
    speed_deg_s: float

    def summary(self) -> dict[str, Any]:
        """A small JSON document of what was taken (for a campaign's state file)."""
        return {
            "channels": list(self.channels),
            "polarizer_deg": list(self.polarizer_deg),
            "reference_deg": list(self.reference_deg),
            "exposures_s": list(self.exposures_s),
            "settings": list(self.settings),
            "speed_deg_s": self.speed_deg_s,
            "acquisitions": int(np.prod(self.means.shape[:3])),
        }


def _settings(settings: Sequence[bool]) -> list[tuple[str, bool]]:
    chosen = [(name, on) for name, on in SETTINGS if on in [bool(s) for s in settings]]
    if not chosen:
        raise ValueError("choose at least one compensation setting (on, off or both)")
    return chosen


def acquire_polarization(
    client: CamdClient,
    *,
    channels: Sequence[int] | None = None,
    exposures_s: Sequence[float] = DEFAULT_EXPOSURES_S,
    step_deg: float = DEFAULT_STEP_DEG,
    settings: Sequence[bool] = (True, False),
    progress: Progress | None = None,
) -> PolarizationScan:
    """Take a reference-polariser scan through the polarising channels (docs/physics.md §4).

    ``channels``: polarising channels (default: all of the wheel's); ``settings``: the
    compensation settings to take (True: compensated), compensated first. For each setting,
    each exposure and each reference angle the polariser is set and one pass through the
    channels is taken. The polariser is taken out and the wheel's compensation setting
    restored afterwards (the exposure stays at the last one). ValueError for channels without
    a polariser or bad exposures; RuntimeError when a channel's frame was lost; the client's
    CamdError for anything the daemon refuses.
    """
    angles = reference_angles_deg(step_deg)
    exposures = [float(e) for e in exposures_s]
    if not exposures or any(not (math.isfinite(e) and e > 0.0) for e in exposures):
        raise ValueError(f"give one or more exposures > 0 s, got {list(exposures_s)}")
    chosen_settings = _settings(settings)
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
    shape = (len(chosen_settings), len(exposures), len(angles), len(chosen))
    means = np.full(shape, np.nan)
    header_centre = np.full(shape, np.nan)
    exposure_docs: list[list[dict[str, Any]]] = []
    total = len(chosen_settings) * len(exposures) * len(angles)
    done = 0
    speed = float(wheel["speed_deg_s"])

    def restore() -> None:
        client.set_polarizer(None)
        if client.wheel()["compensation"] != was_compensated:
            client.set_wheel_compensation(was_compensated)

    try:
        for s, (name, compensated) in enumerate(chosen_settings):
            exposure_docs.append([])
            for e, exposure_s in enumerate(exposures):
                exposure_doc: dict[str, Any] = {}
                for a, angle in enumerate(angles):
                    client.set_polarizer(angle)
                    doc = client.wheel_acquire(
                        chosen, exposure_s=exposure_s, compensated=compensated
                    )
                    exposure_doc = dict(doc["exposure"])
                    speed = float(doc["speed_deg_s"])
                    got = {str(f["channel"]): f for f in doc["frames"]}
                    missing = [k for k in keys if k not in got]
                    if missing:
                        raise RuntimeError(
                            f"the frame(s) of channel(s) {', '.join(missing)} were lost at "
                            f"{angle:g} deg ({exposure_s * 1e3:g} ms, {name}); see `camctl "
                            "events` and repeat"
                        )
                    for c, k in enumerate(keys):
                        means[s, e, a, c] = got[k]["mean"]
                        header_centre[s, e, a, c] = got[k]["header_centre_deg"]
                    done += 1
                    if progress is not None:
                        progress(done, total, f"{name} {exposure_s * 1e3:g} ms, {angle:g} deg")
                exposure_docs[s].append({k: exposure_doc.get(k) for k in EXPOSURE_KEYS})
    except BaseException:
        # Leave the polariser out and the setting as found, without hiding the first error.
        with contextlib.suppress(Exception):
            restore()
        raise
    restore()
    return PolarizationScan(
        channels=chosen,
        polarizer_deg=[float(axes[c] or 0.0) for c in chosen],  # all have one (checked)
        reference_deg=angles,
        exposures_s=exposures,
        settings=[name for name, _ in chosen_settings],
        means=means,
        header_centre_deg=header_centre,
        exposure=exposure_docs,
        speed_deg_s=speed,
    )


def fit_polarization_scan(scan: PolarizationScan) -> dict[str, Any]:
    """Each channel's azimuth per setting and exposure, fitted to the scan's frame means.

    Returns::

        {"channels": [...], "reference_deg": [...], "exposure_ms": [...],
         "exposure_s": [...], "frame_time_s": [...],          # as the registers set them
         "azimuth_deg": {"compensated": {"10": [...], ...}, "uncompensated": {...}},
         "azimuth_error_deg": {...}, "shift_deg": {...},      # azimuth - the polariser's axis
         "predicted_shift_deg": {"compensated": [...], "uncompensated": [...]},
         "spread_deg": {"compensated": x, "uncompensated": x},
         "spread_by_channel_deg": {...}, "predicted_spread_deg": {...}}

    with a key per setting the scan holds. ``spread_deg`` is, per setting, the largest over
    the channels of the spread of a channel's azimuths across the exposures
    (``azimuth_spread_deg``); ``predicted_*`` come from the daemon's eq-4 centre offsets.
    """
    keys = [str(c) for c in scan.channels]
    first = scan.exposure[0]
    result: dict[str, Any] = {
        "channels": list(scan.channels),
        "reference_deg": list(scan.reference_deg),
        "exposure_ms": [e * 1e3 for e in scan.exposures_s],
        # The same registers for every setting: report the first's.
        "exposure_s": [doc["exposure_s"] for doc in first],
        "frame_time_s": [doc["frame_time_s"] for doc in first],
        "azimuth_deg": {},
        "azimuth_error_deg": {},
        "shift_deg": {},
        "predicted_shift_deg": {},
        "spread_deg": {},
        "spread_by_channel_deg": {},
        "predicted_spread_deg": {},
    }
    for s, name in enumerate(scan.settings):
        azimuths: dict[str, list[float]] = {k: [] for k in keys}
        errors: dict[str, list[float]] = {k: [] for k in keys}
        for e in range(len(scan.exposures_s)):
            for c, k in enumerate(keys):
                fit = fit_polarization(scan.reference_deg, scan.means[s, e, :, c])
                azimuths[k].append(fit.azimuth_deg)
                errors[k].append(fit.azimuth_error_deg)
        predicted = [float(doc["centre_offset_deg"] or 0.0) for doc in scan.exposure[s]]
        by_channel = {k: azimuth_spread_deg(azimuths[k]) for k in keys}
        result["azimuth_deg"][name] = azimuths
        result["azimuth_error_deg"][name] = errors
        result["shift_deg"][name] = {
            k: [axial_difference_deg(a - scan.polarizer_deg[c]) for a in azimuths[k]]
            for c, k in enumerate(keys)
        }
        result["predicted_shift_deg"][name] = predicted
        result["spread_by_channel_deg"][name] = by_channel
        result["spread_deg"][name] = max(by_channel.values())
        result["predicted_spread_deg"][name] = float(np.ptp(predicted))
    return result


def measure_polarization_azimuth(
    client: CamdClient,
    *,
    channels: Sequence[int] | None = None,
    exposures_s: Sequence[float] = DEFAULT_EXPOSURES_S,
    step_deg: float = DEFAULT_STEP_DEG,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Azimuth of each polarising channel per exposure, with and without delay compensation:
    ``fit_polarization_scan(acquire_polarization(...))`` with both settings (see both)."""
    scan = acquire_polarization(
        client, channels=channels, exposures_s=exposures_s, step_deg=step_deg, progress=progress
    )
    return fit_polarization_scan(scan)


# -- the scan in HDF5 -------------------------------------------------------------------------


def write_polarization_scan(path: str | Path, scan: PolarizationScan) -> Path:
    """Write ``scan`` to a new HDF5 file (refused if it exists) and return its path.

    ``/means`` and ``/header_centre_deg`` are (setting, exposure, reference angle, channel)
    arrays whose ``axes`` attribute names the axes; the axes' values are the datasets
    ``/settings``, ``/exposure_s``, ``/reference_deg`` and ``/channels`` (with
    ``/polarizer_deg``, each channel's axis). The exposure documents are (setting, exposure)
    datasets under ``/exposure`` (one per ``EXPOSURE_KEYS``; NaN where the daemon gave null).
    Root attributes: ``format``, ``format_version``, ``speed_deg_s``, ``units``.
    """
    import h5py

    path = Path(path)
    axes = np.array(["setting", "exposure", "reference_angle", "channel"], dtype=object)
    text = h5py.string_dtype()
    try:
        f = h5py.File(path, "x")
    except (OSError, FileExistsError) as exc:
        raise OSError(f"cannot create {path} (it must not exist): {exc}") from None
    with f:
        f.attrs["format"] = SCAN_FORMAT
        f.attrs["format_version"] = SCAN_FORMAT_VERSION
        f.attrs["speed_deg_s"] = scan.speed_deg_s
        f.attrs["units"] = "means in DN (whole-frame mean), angles in deg, times in s"
        for name, data, what in (
            ("means", scan.means, "mean signal of each frame (DN)"),
            ("header_centre_deg", scan.header_centre_deg, "imaging centre from the header"),
        ):
            ds = f.create_dataset(name, data=np.asarray(data, dtype=np.float64))
            ds.attrs["axes"] = axes.astype(text)
            ds.attrs["description"] = what
        f.create_dataset("settings", data=np.array(scan.settings, dtype=object), dtype=text)
        f["settings"].attrs["description"] = "axis 0: delay compensation setting"
        f.create_dataset("exposure_s", data=np.asarray(scan.exposures_s, dtype=np.float64))
        f["exposure_s"].attrs["description"] = "axis 1: exposure asked for (s)"
        f.create_dataset("reference_deg", data=np.asarray(scan.reference_deg, dtype=np.float64))
        f["reference_deg"].attrs["description"] = "axis 2: reference polariser axis (deg)"
        f.create_dataset("channels", data=np.asarray(scan.channels, dtype=np.int32))
        f["channels"].attrs["description"] = "axis 3: wheel channel"
        f.create_dataset("polarizer_deg", data=np.asarray(scan.polarizer_deg, dtype=np.float64))
        f["polarizer_deg"].attrs["description"] = "each channel's polariser axis (deg)"
        group = f.create_group("exposure")
        group.attrs["axes"] = axes[:2].astype(text)
        for key in EXPOSURE_KEYS:
            values = [[_number(doc.get(key)) for doc in row] for row in scan.exposure]
            group.create_dataset(key, data=np.asarray(values, dtype=np.float64))
    return path


def read_polarization_scan(path: str | Path) -> PolarizationScan:
    """Read a scan written by ``write_polarization_scan``; OSError if it is not one."""
    import h5py

    path = Path(path)
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise OSError(f"cannot open {path} as HDF5: {exc}") from None
    with f:
        if f.attrs.get("format") != SCAN_FORMAT:
            raise OSError(f"{path} is not a polarisation scan (no format={SCAN_FORMAT!r})")
        settings = [s.decode() if isinstance(s, bytes) else str(s) for s in f["settings"][...]]
        group = f["exposure"]
        table = {key: np.asarray(group[key][...], dtype=np.float64) for key in EXPOSURE_KEYS}
        exposure: list[list[dict[str, Any]]] = [
            [
                {key: _plain(float(table[key][s, e])) for key in EXPOSURE_KEYS}
                for e in range(table["exposure_s"].shape[1])
            ]
            for s in range(len(settings))
        ]
        for row in exposure:
            for doc in row:
                for key in ("exposure_lines", "window_rows"):  # whole numbers in the API
                    if doc[key] is not None:
                        doc[key] = int(doc[key])
        return PolarizationScan(
            channels=[int(c) for c in f["channels"][...]],
            polarizer_deg=[float(v) for v in f["polarizer_deg"][...]],
            reference_deg=[float(v) for v in f["reference_deg"][...]],
            exposures_s=[float(v) for v in f["exposure_s"][...]],
            settings=settings,
            means=np.asarray(f["means"][...], dtype=np.float64),
            header_centre_deg=np.asarray(f["header_centre_deg"][...], dtype=np.float64),
            exposure=exposure,
            speed_deg_s=float(f.attrs["speed_deg_s"]),
        )


def _number(value: Any) -> float:
    return math.nan if value is None else float(value)


def _plain(value: float) -> float | None:
    return None if math.isnan(value) else value
