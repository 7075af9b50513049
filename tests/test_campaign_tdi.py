"""The shipped TDI campaigns (tdi_snr_stages, tdi_snr_model, noise_vs_stages) in their --quick
forms, each through `camctl campaign run NAME --sim` (its own simulated camera of the
campaign's profile, HTTP, the runner, HDF5, the report), with the numbers checked against the
profile's physics; and an interrupted-then-resumed shipped campaign against an uninterrupted
one."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from camd.campaign.loading import load_campaign
from camd.campaign.runner import CampaignInterrupted
from camd.cli.camctl_campaign import campaigns_dir, run_on_own_sim
from camd.sensor.profile import load_profile
from tests.campaign_support import report_images, run_shipped

# Not ``exclusive``: the numbers are statistics of the simulator's seeded frames, which a late
# host receives late but whole (the simulated camera loses no frame for lateness:
# firmware_models/fx3.py), on the simulator's ideal stage. Checked beside `stress-ng --cpu 2`.


def test_tdi_snr_stages(tmp_path: Path) -> None:
    r = run_shipped("tdi_snr_stages", tmp_path)["results"]
    assert len(report_images(tmp_path)) == 2
    assert r["stages"] == [1, 10]  # the quick form
    assert abs(r["mean"][0] - 17.0) < 0.5  # the light set from the trial scan (TAO12 §5.1)
    # Ten stages of the same scene: ten times the mean (black included), to the noise.
    assert r["mean"][1] / r["mean"][0] == pytest.approx(10.0, rel=0.01)
    # Independent stages: PSNR up by 10 lg 10 = 10 dB; TAO12 eq 28 predicts less.
    gain_db = r["psnr_db"][1] - r["psnr_db"][0]
    assert gain_db == pytest.approx(10.0, abs=0.5)
    assert r["tao12_db"][1] < r["psnr_db"][1] - 1.0
    assert r["rms_sqrt_m_db"] < 0.5 < r["rms_tao12_db"]


def test_tdi_snr_model(tmp_path: Path) -> None:
    r = run_shipped("tdi_snr_model", tmp_path)["results"]
    assert len(report_images(tmp_path)) == 3
    stages = [1, 2, 3, 5, 8, 12, 20]
    assert r["stages"] == stages and r["condition_names"] == ["fig6a", "12lx"]
    assert len(r["measured_db"]) == 2 and all(len(m) == len(stages) for m in r["measured_db"])
    assert set(r["model_db"]) == {"tao12", "sqrt_m", "quadrature"}
    for model, curves in r["model_db"].items():
        for measured, curve in zip(r["measured_db"], curves, strict=True):
            assert curve[0] == pytest.approx(measured[0]), model  # scaled from M = 1
    assert r["best_model"] == "sqrt_m" and r["best_rms_db"] < 0.3
    # The sensor noise the models use against the profile's physics at gain x8, 8-bit output:
    # K = 14 uV/e- x 8 / (1 V / 1024) / 4 DN per output DN; noise^2 = K^2 (e + read^2).
    profile = load_profile("ibis5")
    k = profile.conversion_gain_uv_per_e.value * 1e-6 * 8 / (1.0 / 1024) / 4
    read_e = profile.read_noise_e.value
    for signal, sigma_cmos in zip((s[0] for s in r["signal_dn"]), r["sigma_cmos_dn"], strict=True):
        expected = k * math.sqrt(signal / k + read_e**2)
        assert sigma_cmos == pytest.approx(expected, rel=0.1)


def test_noise_vs_stages(tmp_path: Path) -> None:
    r = run_shipped("noise_vs_stages", tmp_path)["results"]
    assert len(report_images(tmp_path)) == 2
    assert r["stages"] == [1, 2, 4, 8, 16, 32, 64]
    assert r["noise_lsb"][0] == pytest.approx(5.4, abs=0.3)  # DONG16's staring dark noise
    for m, noise in zip(r["stages"], r["noise_lsb"], strict=True):
        assert noise == pytest.approx(r["noise_lsb"][0] / math.sqrt(m), rel=0.06), m
    assert all(abs(x - 200.0) < 1.0 for x in r["dark_mean_lsb"])  # the AFE offset, 200 DN


def test_shipped_campaign_interrupted_and_resumed_matches(tmp_path: Path) -> None:
    """A sweep over conditions with results feeding later steps: stopped after the first
    condition, resumed on a new simulated camera, results.json is byte-identical."""
    spec = load_campaign(campaigns_dir() / "tdi_snr_model.yaml")
    run_on_own_sim(spec, tmp_path / "straight", quick=True)
    with pytest.raises(CampaignInterrupted):
        run_on_own_sim(spec, tmp_path / "resumed", quick=True, stop_after="condition[0]/models")
    assert not (tmp_path / "resumed" / "results.json").exists()
    run_on_own_sim(spec, tmp_path / "resumed", quick=True)
    a = (tmp_path / "straight" / "results.json").read_text()
    b = (tmp_path / "resumed" / "results.json").read_text()
    assert a == b
