"""The two hr400 campaigns of YE23 (§5.1 emva_snr_exposure, §5.2 polarization_delay), quick
forms, as a user runs them: camctl campaign run NAME --sim --quick --json --out DIR -> its own
camd serve --sim (hr400) -> results.json, raw HDF5, report.md/html with PNG plots.

The expected numbers are worked out here from docs/physics.md and the hr400 profile's values
(config/profiles/hr400.toml), not taken from the campaign's own model columns:

    K = 10 uV/e- x 4096 DN / 1 V = 0.04096 DN/e-; read noise 37.2 e-; full well 80 ke-
    2x2 binning (§3): signal x4, temporal noise x2
    a binned pixel's noise^2 = 4 (S + D + 37.2^2 + 1/(12 K^2)) e-^2, S per pixel
    eq 10 reads sqrt(19/20) c4(20) = 0.962 sigma, eq 13 reads 1.069 mu / sigma (A = 20)
    T_line = 513 / 25 MHz = 20.52 us, T_frame = (n + k + 1) T_line (§3, §4 eq 6)
    uncompensated centre offset w (T_frame / 2 - T_center), w = 73.245 deg/s, T_center = 60 ms
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import h5py
import numpy as np
import pytest

from camd.analysis.emva import eq10_expectation_factor, eq13_expectation_factor, photon_transfer
from camd.motion.polarization_run import fit_polarization_scan, read_polarization_scan
from tests.campaign_support import report_images, run_shipped
from tests.test_emva import eq10_factor, eq13_factor

K_DN_PER_E = 10e-6 * 4096 / 1.0
READ_NOISE_E = 37.2
FULL_WELL_E = 80_000.0
DARK_E_PER_S = 30.0
QUANTISATION_E2 = 1.0 / 12.0 / K_DN_PER_E**2
FRAMES = 20

T_LINE_S = 513 / 25e6
W_DEG_S = 73.245
T_CENTER_S = 0.060
WINDOW_ROWS = 534
AXES_DEG = {"10": 0.0, "11": 60.0, "12": 120.0}


def check_report(out: Path, plots: int) -> None:
    """The report's images decode; every check passed."""
    assert len(report_images(out)) == plots
    assert "FAIL" not in (out / "report.md").read_text()
    doc = json.loads((out / "results.json").read_text())
    assert doc["checks"] and all(c["passed"] for c in doc["checks"])


# -- the pure functions the campaigns added to camd.analysis.emva -----------------------------


def test_eq10_and_eq13_expectation_factors_are_the_textbook_ones() -> None:
    for a in (3, 5, 20, 200):
        assert eq10_expectation_factor(a) == pytest.approx(eq10_factor(a), rel=1e-12)
        assert eq13_expectation_factor(a) == pytest.approx(eq13_factor(a), rel=1e-12)
    assert eq10_expectation_factor(20) == pytest.approx(0.96194, abs=1e-5)
    assert eq13_expectation_factor(20) == pytest.approx(1.06883, abs=1e-5)
    with pytest.raises(ValueError, match="whole number >= 3"):
        eq13_expectation_factor(2)


def test_photon_transfer_recovers_gain_and_dark_variance() -> None:
    mean = np.array([100.0, 400.0, 900.0, 1600.0])
    fit = photon_transfer(mean, 0.04096 * mean + 9.3)
    assert fit.gain_dn_per_e == pytest.approx(0.04096, rel=1e-12)
    assert fit.dark_variance_dn2 == pytest.approx(9.3, rel=1e-12)
    assert fit.points == 4 and fit.gain_error_dn_per_e < 1e-12
    # Noise of known size: the standard error matches the scatter of the slope by hand.
    noisy = photon_transfer([1.0, 2.0, 3.0], [1.0, 3.0, 2.0])  # slope 0.5, residuals 1/2 each
    assert noisy.gain_dn_per_e == pytest.approx(0.5)
    assert noisy.gain_error_dn_per_e == pytest.approx(math.sqrt(1.5 / 2.0))  # s^2 / Sxx
    with pytest.raises(ValueError, match="at least 2"):
        photon_transfer([1.0], [1.0])
    with pytest.raises(ValueError, match="different signal levels"):
        photon_transfer([2.0, 2.0], [1.0, 3.0])


# -- YE23 §5.1 -----------------------------------------------------------------------------------


def binned_snr_model(signal_dn: float, exposure_s: float) -> float:
    """What eq 13 should read on a 2x2-binned pixel holding ``signal_dn`` above dark."""
    pixel_e = signal_dn / (4 * K_DN_PER_E)
    variance_e2 = 4 * (pixel_e + DARK_E_PER_S * exposure_s + READ_NOISE_E**2 + QUANTISATION_E2)
    return eq13_factor(FRAMES) * 4 * pixel_e / math.sqrt(variance_e2)


def test_emva_snr_exposure_quick(tmp_path: Path) -> None:
    out = tmp_path / "emva"
    r = run_shipped("emva_snr_exposure", out)["results"]
    assert {"dark_noise_dn", "dark_noise_e", "exposure_ms", "snr"} <= set(r)
    assert r["exposure_ms"] == [5, 30, 60]
    # Whole lines: round(T / 20.52 us) = 244, 1462, 2924.
    assert r["exposure_lines"] == [244, 1462, 2924]
    assert r["exposure_set_ms"] == pytest.approx([n * T_LINE_S * 1e3 for n in (244, 1462, 2924)])

    # Saturation: every pixel at 80 ke- x K = 3276.8 DN above black, rounded with the black
    # level (100 DN) to 3377 - 100 = 3277 DN; four of them.
    assert r["saturation_dn"] == pytest.approx(4 * 3277, abs=1.0)
    assert r["saturated_noise_dn"] == 0.0
    # The light: 60 ms gives 80 % of it (probe and target at the same exposure).
    assert r["signal_dn"][-1] == pytest.approx(0.8 * 4 * 3277, rel=0.01)
    # Linear in the exposure: the signal scales with the lines.
    assert r["signal_dn"][0] / r["signal_dn"][-1] == pytest.approx(244 / 2924, rel=0.01)

    # System gain by photon transfer: the profile's K within 5 % (the fit's 2 % over 3 points).
    assert r["system_gain_dn_per_e"] == pytest.approx(K_DN_PER_E, rel=0.05)

    # Dark noise at 5 ms: eq 10 of 4 summed pixels, read noise + dark shot + quantisation.
    dark_e2 = READ_NOISE_E**2 + DARK_E_PER_S * 244 * T_LINE_S + QUANTISATION_E2
    expected_dark_dn = eq10_factor(FRAMES) * 2 * K_DN_PER_E * math.sqrt(dark_e2)  # 2.983 DN
    assert r["dark_noise_dn"] == pytest.approx(expected_dark_dn, rel=0.03)
    assert r["dark_noise_dn"] == r["exposure_dark_noise_dn"][0]
    assert r["dark_noise_e"] == pytest.approx(r["dark_noise_dn"] / r["system_gain_dn_per_e"])
    # ... against YE23's 37.2 e- single-pixel figure, x2 for the binned sum: eq 10 reads 3.8 %
    # low, quantisation adds 1.8 %.
    assert r["dark_noise_e_nominal"] == pytest.approx(74.4)
    assert r["dark_noise_e"] == pytest.approx(72.85, rel=0.05)

    # SNR against the noise model at each exposure (measured signal in, eq 13's bias in).
    for signal, lines, snr, model in zip(
        r["signal_dn"], (244, 1462, 2924), r["snr"], r["snr_model"], strict=True
    ):
        hand = binned_snr_model(signal, lines * T_LINE_S)
        assert model == pytest.approx(hand, rel=1e-6)
        assert snr == pytest.approx(hand, rel=0.03)
    # At 80 % of saturation the SNR is shot-noise limited: 256 ke- in the binned pixel,
    # sqrt(256000 + 4 x 1435) = 511.6 e- of noise, x 1.069.
    assert r["snr"][-1] == pytest.approx(
        1.0688 * 256_000 / math.sqrt(256_000 + 4 * 1435.3), rel=0.03
    )
    assert r["snr"][0] < r["snr"][1] < r["snr"][2]

    # The raw data: one HDF5 recording per acquisition, binned 32 x 1024 frames.
    files = json.loads((out / "results.json").read_text())["files"]
    assert "exposures[2]/lit" in files and "saturated" in files
    with h5py.File(out / files["exposures[2]/lit"], "r") as f:
        assert f["frames"].shape == (FRAMES, 32, 1024)
        # Its NeXus entry names the campaign step that made it (an NXnote: docs/scan.md).
        note = f["entry/campaign_step"]
        assert note.attrs["NX_class"] == "NXnote"
        text = note["description"][()].decode()
        assert text.startswith("campaign emva_snr_exposure: step "), text
        assert text.endswith(" acquire exposures[2]/lit"), text
    check_report(out, plots=3)


# -- YE23 §5.2 -----------------------------------------------------------------------------------


def offset_deg(exposure_lines: int) -> float:
    """Uncompensated imaging centre minus channel centre, eq 1: w (T_frame / 2 - T_center)."""
    frame_s = (exposure_lines + WINDOW_ROWS + 1) * T_LINE_S
    return W_DEG_S * (frame_s / 2 - T_CENTER_S)


def axial(angle_deg: float) -> float:
    return (angle_deg + 90.0) % 180.0 - 90.0


def test_polarization_delay_quick(tmp_path: Path) -> None:
    out = tmp_path / "pol"
    r = run_shipped("polarization_delay", out)["results"]
    assert {"exposure_ms", "azimuth_deg", "spread_deg"} <= set(r)
    assert r["exposure_ms"] == [3.0, 60.0]
    assert set(r["azimuth_deg"]) == set(r["spread_deg"]) == {"compensated", "uncompensated"}
    lines = (146, 2924)  # round(3 ms / T_line), round(60 ms / T_line)
    assert r["frame_time_ms"] == pytest.approx([(n + 535) * T_LINE_S * 1e3 for n in lines])
    for setting, azimuths in r["azimuth_deg"].items():
        assert set(azimuths) == set(AXES_DEG)
        for channel, values in azimuths.items():
            assert len(values) == 2
            for value, n in zip(values, lines, strict=True):
                shift = 0.0 if setting == "compensated" else offset_deg(n)  # -3.8829, -1.7953
                # The fits' standard errors are 0.0001 .. 0.0005 deg here.
                assert abs(axial(value - AXES_DEG[channel] - shift)) < 0.005
    # Spread across 3 and 60 ms: w (T_frame(60) - T_frame(3)) / 2 = 2.08765 deg without
    # compensation (independent of the window), 0 with it; eq 8's uncertainty is 0.087 deg.
    predicted = W_DEG_S * (2924 - 146) * T_LINE_S / 2
    assert predicted == pytest.approx(2.08765, abs=1e-5)
    assert r["spread_deg"]["uncompensated"] == pytest.approx(predicted, abs=0.005)
    assert r["spread_deg"]["compensated"] < 0.005
    assert r["compensated_spread_limit_deg"] == pytest.approx(0.0870, abs=1e-4)

    # The raw data: the frame means per setting, exposure, reference angle and channel.
    scan_file = out / json.loads((out / "results.json").read_text())["files"]["scan"]
    with h5py.File(scan_file, "r") as f:
        assert list(f["means"].attrs["axes"]) == ["setting", "exposure", "reference_angle",
                                                  "channel"]  # fmt: skip
        assert f["means"].shape == (2, 2, 12, 3)
    scan = read_polarization_scan(scan_file)
    assert scan.settings == ["compensated", "uncompensated"]
    assert scan.reference_deg == [30.0 * i for i in range(12)]
    assert scan.channels == [10, 11, 12] and scan.polarizer_deg == [0.0, 60.0, 120.0]
    assert [doc["exposure_lines"] for doc in scan.exposure[1]] == list(lines)
    # Malus through two polarisers: with compensation each channel is brightest with the
    # reference polariser on its axis (0, 60, 120 deg, or 180 deg on: angles 0, 2, 4 mod 6).
    assert np.all(scan.means[0].argmax(axis=1) % 6 == [0, 2, 4])
    assert fit_polarization_scan(scan)["azimuth_deg"] == r["azimuth_deg"]  # the file is the data
    check_report(out, plots=2)
