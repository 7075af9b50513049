"""The frame stream over the full stack, as a user drives it.

camctl (in process; one test as a command) -> HTTP on loopback -> camd serve -> START_STREAM over
the pty -> simulated FPGA -> camera model -> LVDS link -> stream engine -> Unix socket -> simulated
FX3 pyusb backend -> usb.core.find / bulk reads in the daemon's FrameStream -> recorder (HDF5) ->
read back here.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from camd.client import CamdClient, CamdError
from camd.store import read_recording
from tests.nexus_support import nexus_plot, nxcheck
from tests.test_camctl import camctl, camctl_command_json, camctl_json
from tests.test_sensor_stack import serve

# Not ``exclusive``: counted streams of small frames (at most 300 of 32 x 2048 pixels, 40 MB,
# well inside the daemon's queue), which a late host receives late but whole (the simulated
# camera loses no frame for lateness: firmware_models/fx3.py); the faults are injected and
# counted exactly. Checked beside `stress-ng --cpu 2`.

HEADLINE = ["frames", "lost", "corrupt", "overruns", "mpix_per_s", "mbyte_per_s"]
ROWS = 32  # a small window keeps the simulator fast


@pytest.fixture(scope="module")
def url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    with serve(tmp_path_factory.mktemp("camd-stream"), "fpga") as daemon:
        camctl_json(daemon.url, "reg", "write", f"WIN_ROWS={ROWS}", "EXPOSURE=4")
        yield daemon.url
    assert daemon.exit_code in (0, -15), daemon.log_path.read_text()


def test_stream_json_has_the_contract_keys_and_every_frame(url: str) -> None:
    before = camctl_command_json(url, "sim", "stream")
    doc = camctl_command_json(url, "stream", "--frames", "40", "--mode", "tdi", "--stages", "8")
    after = camctl_command_json(url, "sim", "stream")
    assert list(doc)[: len(HEADLINE)] == HEADLINE
    assert (doc["frames"], doc["lost"], doc["corrupt"], doc["overruns"]) == (40, 0, 0, 0)
    assert (doc["mode"], doc["stages"], doc["rows"], doc["cols"], doc["bits"]) == (
        "tdi", 8, ROWS, 2048, 12,
    )  # fmt: skip
    assert doc["frames_sent"] == 40 and after["sent"] - before["sent"] == 40
    # 40 frames of 32 x 2048 pixels plus a 64-byte header each.
    assert doc["bytes"] == 40 * (64 + 2 * ROWS * 2048)
    assert doc["mbyte_per_s"] == pytest.approx(doc["bytes"] / doc["elapsed_s"] / 1e6, rel=0.02)
    assert doc["mpix_per_s"] == pytest.approx(
        doc["mbyte_per_s"] * ROWS * 2048 / (64 + 4 * ROWS * 1024), rel=0.02
    )
    with CamdClient(url) as client:
        metrics = client.metrics()
    assert "camd_stream_frames 40.0" in metrics and "camd_stream_lost 0.0" in metrics
    assert "camd_stream_active 0.0" in metrics
    # A second stream carries on the frame counter where the first ended.
    again = camctl_command_json(url, "stream", "--frames", "3", "--mode", "area")
    assert again["first_counter"] == doc["first_counter"] + 40 and again["stages"] == 0


def test_stare_records_frames_bit_exactly_with_metadata(url: str, tmp_path: Path) -> None:
    camctl_json(url, "reg", "write", "TEST_PATTERN.mode=ramp")
    try:
        doc = camctl_json(url, "stare", "--frames", "6", "--out", str(tmp_path / "ramp.h5"))
    finally:
        camctl_json(url, "reg", "write", "TEST_PATTERN.mode=off")
    rec = read_recording(tmp_path / "ramp.h5")
    assert doc["out"] == str(tmp_path / "ramp.h5") and doc["frames"] == 6 == len(rec.frames)
    # The sensor's ramp test pattern, (row + column) mod 2**12, through the trained LVDS link.
    ramp = (np.add.outer(np.arange(ROWS), np.arange(2048)) & 0xFFF).astype(np.uint16)
    for frame in rec.frames:
        assert np.array_equal(frame, ramp)
    assert rec.crc_mismatches() == []
    counters = rec.columns["frame_counter"].astype(np.int64)
    assert np.diff(counters).tolist() == [1] * 5
    assert rec.columns["gap_before"].tolist() == [0] * 6
    # Device timestamps are one frame period apart (model time, to the nanosecond).
    period_ns = round(rec.attrs["line_period_s"] * 1e9)
    assert np.abs(np.diff(rec.columns["timestamp_ns"].astype(np.int64)) - period_ns).max() <= 1
    timing = camctl_json(url, "timing")
    assert rec.attrs["line_period_s"] == pytest.approx(timing["frame_period_s"], abs=1e-9)
    assert rec.attrs["mode"] == "area" and rec.attrs["bits"] == 12
    assert rec.metadata["profile"]["profile"] == "hr400"
    assert rec.metadata["registers"]["WIN_ROWS"] == ROWS
    assert rec.metadata["registers"]["TEST_PATTERN"] == 2  # ramp, while recording
    assert rec.metadata["timing"]["window_rows"] == ROWS
    assert rec.metadata["timing"]["line_period_s"] == pytest.approx(513 / 25e6)
    assert rec.metadata["stream"]["frames"] == 6 and rec.metadata["stream"]["lost"] == 0
    # Flags say the frames are a test pattern.
    assert all(int(f) & 0x2 for f in rec.columns["flags"])
    # A NeXus viewer finds the frames as images against frame counter, row and column
    # (docs/stream.md, "NeXus").
    nexus = nexus_plot(tmp_path / "ramp.h5")
    assert (nexus["signal"], nexus["shape"]) == ("frames", (6, ROWS, 2048))
    assert nexus["axes"] == [("frame_counter", (6,)), ("row", (ROWS,)), ("column", (2048,))]
    assert np.array_equal(nexus["signal_values"], rec.frames)
    assert np.array_equal(nexus["axis_values"][0], rec.columns["frame_counter"])
    det = nexus["detector"]
    assert det["bit_depth_readout"] == (12, None) and det["local_name"] == ("hr400", None)
    assert det["frame_time"][0] == pytest.approx(rec.attrs["line_period_s"])
    assert nexus["title"] == f"frames, hr400, {ROWS} x 2048, area mode"
    assert nexus["signal_attrs"]["interpretation"] == "image"
    # The daemon names the simulated camera's scene (the file's NXsample), and nothing in the
    # entry is for a NeXus validator to report: only camd's root layout (tests/test_nexus.py).
    with CamdClient(url) as client:
        scene = client.sim_settings()["scene"]
    assert rec.metadata["sample"] == {"scene": scene}
    found = nxcheck(tmp_path / "ramp.h5")
    assert found["error"] == [] and "NXsample: /entry/sample" in found["groups"]
    assert [w for w in found["warning"] if w.startswith("/entry")] == []


def test_binned_stare_halves_the_frame_and_adds_two_bits(url: str, tmp_path: Path) -> None:
    doc = camctl_json(url, "stare", "--frames", "2", "--binning", "--out", str(tmp_path / "b.h5"))
    assert (doc["rows"], doc["cols"], doc["bits"], doc["binning"]) == (ROWS // 2, 1024, 14, "2x2")
    rec = read_recording(tmp_path / "b.h5")
    assert rec.frames.shape == (2, ROWS // 2, 1024)
    assert all(int(f) & 0x1 for f in rec.columns["flags"])  # BINNED_2X2


def test_bad_requests_are_refused_and_leave_the_daemon_idle(url: str, tmp_path: Path) -> None:
    proc = camctl(url, "stream", "--frames", "2", "--mode", "tdi", "--stages", str(ROWS + 1))
    assert proc.returncode == 1
    assert f"stages = {ROWS + 1} does not fit the window of {ROWS} rows" in proc.stderr
    existing = tmp_path / "there.h5"
    existing.write_bytes(b"keep me")
    proc = camctl(url, "stare", "--frames", "2", "--out", str(existing))
    assert proc.returncode == 2 and "already exists" in proc.stderr
    assert existing.read_bytes() == b"keep me"
    with CamdClient(url) as client:
        outside = "/etc/camd-test-never.h5"
        with pytest.raises(CamdError, match="is outside the directories the daemon may") as info:
            client.acquire(2, record=outside)
        assert info.value.code == "bad_request"
        with pytest.raises(CamdError, match="frames must be at least 1"):
            client.acquire(0)
        client.write_registers({"WIN_ROWS": ROWS + 1})
        try:
            with pytest.raises(CamdError, match="2x2 binning needs an even window"):
                client.acquire(2, binning="2x2")
        finally:
            client.write_registers({"WIN_ROWS": ROWS})
        assert client.status()["state"] == "idle"
        assert client.stream()["streaming"] is False


def test_injected_faults_are_counted_exactly(tmp_path: Path) -> None:
    inject = "frame_drop=0.05,frame_corrupt=0.03,frame_short=0.03,frame_stall=0.02"
    with serve(tmp_path, "fpga", inject=inject) as daemon:
        camctl_json(daemon.url, "reg", "write", f"WIN_ROWS={ROWS}", "EXPOSURE=4")
        out = tmp_path / "faulty.h5"
        doc = camctl_json(daemon.url, "stream", "--frames", "300", "--mode", "tdi")
        sim = camctl_json(daemon.url, "sim", "stream")
        stare = camctl_json(daemon.url, "stare", "--frames", "60", "--out", str(out))
        sim2 = camctl_json(daemon.url, "sim", "stream")
    assert sim["dropped"] > 0 and sim["corrupted"] > 0 and sim["shortened"] > 0
    assert sim["stalls"] > 0
    # Lost = frames that never arrived: dropped, in flight when the endpoint stalled, and made
    # while it was halted (the device discards them until the host clears the halt).
    assert doc["lost"] == sim["dropped"] + sim["stalls"] + sim["undelivered"]
    assert doc["corrupt"] == sim["corrupted"] and doc["short"] == sim["shortened"]
    assert doc["stalls"] == sim["stalls"]
    assert doc["frames"] + doc["lost"] + doc["corrupt"] + doc["short"] == 300
    assert doc["out_of_order"] == 0 and doc["overruns"] == 0
    # The recording never has a frame out of order, and its gaps are the missing counters.
    rec = read_recording(out)
    counters = rec.columns["frame_counter"].astype(np.int64)
    assert (np.diff(counters) > 0).all()
    assert rec.columns["gap_before"][1:].tolist() == (np.diff(counters) - 1).tolist()
    kinds = ("dropped", "corrupted", "shortened", "stalls", "undelivered")
    damaged = sum(sim2[k] - sim[k] for k in kinds)
    assert len(rec.frames) == stare["frames"] == 60 - damaged
    assert rec.crc_mismatches() == []


def test_sim_stage_speed_and_scene(url: str) -> None:
    timing = camctl_json(url, "timing")
    tracking = camctl_json(url, "sim", "stage", "--track")
    # Synchronous: the image moves one 11 um pitch per TDI line period through the 0.1x
    # optics of the hr400 profile (docs/physics.md §2: T_line,TDI = p / v_image).
    sync = 11e-6 / (0.1 * timing["tdi_line_period_s"])
    assert tracking["sync_speed_m_s"] == pytest.approx(sync, rel=1e-6)
    assert tracking["speed_m_s"] == pytest.approx(sync, rel=1e-6) and tracking["track"] is True
    try:
        fixed = camctl_json(url, "sim", "stage", "--speed-m-s", f"{1.05 * sync:.9g}")
        assert fixed["speed_m_s"] == pytest.approx(1.05 * sync, rel=1e-6)
        assert fixed["track"] is False
    finally:
        camctl_json(url, "sim", "stage", "--track")
    assert camctl_json(url, "sim", "scene", "bars:lux=3") == {"scene": "bars:lux=3"}
    proc = camctl(url, "sim", "scene", "bars:nope=1")
    assert proc.returncode == 1
    assert "unknown scene key 'nope' for bars; keys for bars: photons, lux" in proc.stderr
    camctl_json(url, "sim", "scene", "flat")
