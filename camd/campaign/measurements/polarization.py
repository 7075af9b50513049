"""Polarisation azimuth through the filter wheel, with and without delay compensation
(docs/physics.md §4; YE23 §5.2): the measurement of config/campaigns/polarization_delay.yaml.

``polarization_azimuth`` reads a ``polarization`` acquisition (the frame means of a
reference-polariser scan, camd.motion.polarization_run) and fits each channel's azimuth per
setting and exposure with the code ``camctl wheel azimuth`` uses
(``fit_polarization_scan``: ``camd.analysis.polarization``). It then sets the fit beside the
model: eq 4's imaging-centre offset ``w (T_delay + T_frame / 2 - T_center)`` (0 with
compensation, ``w (T_frame / 2 - T_center)`` without), as the daemon computed it for each
acquisition (``camd.timing.wheel``), and eq 8's uncertainty of that centre.
"""

from __future__ import annotations

import math

from camd.analysis.polarization import axial_difference_deg
from camd.campaign.measurements import Inputs, Results, measurement, require_input
from camd.motion.polarization_run import fit_polarization_scan, read_polarization_scan

TOLERANCE_SIGMAS = 5.0
"""Limits on a fitted azimuth's difference from the model, in standard errors of the fit: a
difference of two azimuths (a spread) has sqrt(2) of that."""


@measurement("polarization_azimuth")
def polarization_azimuth(inputs: Inputs) -> Results:
    """Azimuths of the polarising channels per setting and exposure, against eq 4 and eq 8.

    Input ``scan`` (a ``polarization`` acquisition). Results: as ``camctl wheel azimuth``
    (``fit_polarization_scan``): ``exposure_ms``, ``azimuth_deg``, ``azimuth_error_deg``,
    ``shift_deg`` (azimuth minus the channel's polariser axis), ``predicted_shift_deg`` (eq 4
    centre offsets), ``spread_deg``, ``spread_by_channel_deg``, ``predicted_spread_deg``
    (each ``{setting: ...}``, per channel ``{"10": [...], ...}``), and beside them:

    - ``exposure_set_ms``, ``frame_time_ms``: the exposure the registers gave and T_frame;
    - ``centre_error_deg``: ``{setting: [...]}``, eq 8's uncertainty per exposure;
    - ``compensated_spread_limit_deg``: the largest eq-8 uncertainty with compensation: the
      compensated azimuths should not spread more than the centre angle is known;
    - ``shift_residual_deg``: ``{setting: {channel: [...]}}``, shift minus predicted;
    - ``shift_error_deg``: ``{setting: x}``, the largest |shift - predicted| over channels
      and exposures, and ``shift_tolerance_deg``, ``TOLERANCE_SIGMAS`` times the largest
      standard error of the fits;
    - ``spread_error_deg``: ``{setting: |spread - predicted spread|}`` and
      ``spread_tolerance_deg`` (sqrt(2) x ``shift_tolerance_deg``).
    """
    scan = read_polarization_scan(require_input(inputs, "scan", "polarization_azimuth").path)
    result: Results = fit_polarization_scan(scan)
    first = scan.exposure[0]
    result["exposure_set_ms"] = [float(doc["exposure_s"]) * 1e3 for doc in first]
    result["frame_time_ms"] = [float(doc["frame_time_s"]) * 1e3 for doc in first]
    result["centre_error_deg"] = {
        name: [float(doc["centre_error_deg"]) for doc in scan.exposure[s]]
        for s, name in enumerate(scan.settings)
    }
    if "compensated" in result["centre_error_deg"]:
        result["compensated_spread_limit_deg"] = max(result["centre_error_deg"]["compensated"])
    fit_errors = [
        e
        for by_channel in result["azimuth_error_deg"].values()
        for errors in by_channel.values()
        for e in errors
    ]
    if not all(math.isfinite(e) for e in fit_errors):
        raise ValueError(
            "an azimuth fit has no standard error (3 reference angles leave no residual): "
            "use a smaller step_deg"
        )
    tolerance = TOLERANCE_SIGMAS * max(fit_errors)
    result["shift_residual_deg"] = {
        name: {
            channel: [
                axial_difference_deg(shift - predicted)
                for shift, predicted in zip(
                    shifts, result["predicted_shift_deg"][name], strict=True
                )
            ]
            for channel, shifts in result["shift_deg"][name].items()
        }
        for name in scan.settings
    }
    result["shift_error_deg"] = {
        name: max(abs(r) for rs in by_channel.values() for r in rs)
        for name, by_channel in result["shift_residual_deg"].items()
    }
    result["shift_tolerance_deg"] = tolerance
    result["spread_error_deg"] = {
        name: abs(result["spread_deg"][name] - result["predicted_spread_deg"][name])
        for name in scan.settings
    }
    result["spread_tolerance_deg"] = math.sqrt(2.0) * tolerance
    return result
