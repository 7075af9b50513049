"""The NeXus entry of scan and recording files (camd.store.nexus; docs/scan.md and
docs/stream.md, "NeXus"): what nexusformat finds, the names it reserves, and files of the
formats before it, which read as they did."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import h5py
import numpy as np
import pytest
from nexusformat.nexus import nxload

from camd.protocol.stream import FrameFlags, FrameHeader, StreamMode, crc32
from camd.store.durability import recover_file
from camd.store.recording import FrameRecorder, RecordingError
from camd.store.recording_reading import read_recording
from camd.store.tdi_recording import TdiRecorder, read_tdi_scan
from tests.nexus_support import nexus_plot, nxcheck, silx_nxdata

PROFILE = {
    "profile": "hr400",
    "sensor": "hr400",
    "description": "HR400 2048 x 2048 sCMOS",
    "pitch_m": {"value": 11e-6, "source": "YE23"},
    "output_bits": {"value": 12, "source": "YE23"},
}


def scan_file(path: Path, lines: int = 20, width: int = 24) -> np.ndarray:
    data = np.arange(lines * width, dtype=np.uint32).reshape(lines, width)
    r = TdiRecorder(
        path,
        width=width,
        mode="sum",
        metadata={
            "profile": PROFILE,
            "timing": {"tdi_line_period_s": 250e-6, "exposure_s": 240e-6, "n_lines": 6},
            "scan": {"stages": 4},
        },
    )
    r.append(data, index=np.arange(lines), stages_used=np.full(lines, 4),
             complete=np.ones(lines, bool))  # fmt: skip
    r.close()
    return data


def header(counter: int, pixels: np.ndarray) -> FrameHeader:
    rows, cols = pixels.shape
    return FrameHeader(counter, 1000 * counter, 1000, rows, cols, 12, StreamMode.AREA, 0, 0,
                       FrameFlags(0), pixels.nbytes, crc32(pixels.tobytes()))  # fmt: skip


def test_a_scan_is_an_image_against_line_index_and_column(tmp_path: Path) -> None:
    data = scan_file(tmp_path / "scan.h5")
    p = nexus_plot(tmp_path / "scan.h5")
    assert (p["signal"], p["shape"]) == ("lines", (20, 24))
    assert p["axes"] == [("line_index", (20,)), ("column", (24,))]
    assert np.array_equal(p["signal_values"], data)
    assert p["axis_values"][1].tolist() == list(range(24))
    assert p["detector"] == {
        "description": ("HR400 2048 x 2048 sCMOS", None),
        "local_name": ("hr400", None),
        "x_pixel_size": (11e-6, "m"),
        "y_pixel_size": (11e-6, "m"),
        "bit_depth_readout": (12, None),
        "frame_time": (250e-6, "s"),
        "count_time": (240e-6, "s"),
    }
    with h5py.File(tmp_path / "scan.h5", "r") as f:
        # Hard links: the NeXus signal is the root's dataset, stored once.
        assert f["entry/data/lines"].id == f["lines"].id
        assert f.attrs["format_version"] == 5
        # NXdetector has no field for the TDI settings: they are an NXcollection under it.
        tdi = f["entry/instrument/detector/tdi"]
        assert tdi.attrs["NX_class"] == "NXcollection"
        assert {k: v[()] for k, v in tdi.items()} == {"mode": b"sum", "stages": 4, "window_rows": 6}
    # The reader's metadata are camd's groups, not the NeXus entry.
    assert "entry" not in read_tdi_scan(tmp_path / "scan.h5").metadata


def test_a_recording_is_images_against_frame_counter_row_and_column(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    frames = rng.integers(0, 4096, (5, 3, 7), dtype=np.uint16)
    rec = FrameRecorder(tmp_path / "rec.h5", metadata={"profile": PROFILE}, frames_expected=8)
    for k, px in enumerate(frames):
        rec.add(header(100 + k, px), px, received_ns=k)
    rec.close()
    p = nexus_plot(tmp_path / "rec.h5")
    assert (p["signal"], p["shape"]) == ("frames", (5, 3, 7))  # trimmed from the 8 reserved
    assert p["axes"] == [("frame_counter", (5,)), ("row", (3,)), ("column", (7,))]
    assert np.array_equal(p["signal_values"], frames)
    assert p["axis_values"][0].tolist() == [100, 101, 102, 103, 104]
    assert p["detector"]["bit_depth_readout"] == (12, None)
    assert p["detector"]["frame_time"] == (pytest.approx(1e-6, rel=1e-12), "s")  # 1000 ns
    assert p["title"] == "frames, hr400, 3 x 7, area mode"


def test_a_recording_without_frames_has_an_empty_image(tmp_path: Path) -> None:
    FrameRecorder(tmp_path / "empty.h5", metadata={"profile": PROFILE}).close()
    p = nexus_plot(tmp_path / "empty.h5")
    assert (p["signal"], p["shape"]) == ("frames", (0, 0, 0))
    assert p["axes"] == [("frame_counter", (0,)), ("row", (0,)), ("column", (0,))]


def test_files_of_the_formats_before_nexus_read_as_they_did(tmp_path: Path) -> None:
    data = scan_file(tmp_path / "scan.h5")
    frames = np.arange(2 * 3 * 4, dtype=np.uint16).reshape(2, 3, 4)
    rec = FrameRecorder(tmp_path / "rec.h5", metadata={"profile": PROFILE})
    for k, px in enumerate(frames):
        rec.add(header(k, px), px, received_ns=k)
    rec.close()
    # Made as the formats before (scan 3, recording 2) made them: no entry, no NeXus attributes.
    for name, version in (("scan.h5", 3), ("rec.h5", 2)):
        with h5py.File(tmp_path / name, "r+") as f:
            del f["entry"]
            del f.attrs["NX_class"], f.attrs["default"]
            f.attrs["format_version"] = version
    scan = read_tdi_scan(tmp_path / "scan.h5")
    assert np.array_equal(scan.lines, data) and scan.attrs["format_version"] == 3
    assert np.array_equal(read_recording(tmp_path / "rec.h5").frames, frames)


def test_the_entry_is_not_a_metadata_group_nor_its_attributes_close_attributes(
    tmp_path: Path,
) -> None:
    with pytest.raises(ValueError, match="nor the NeXus entry \\('entry'\\)"):
        TdiRecorder(tmp_path / "a.h5", width=4, mode="sum", metadata={"entry": {"x": 1}})
    r = TdiRecorder(tmp_path / "b.h5", width=4, mode="sum", metadata={})
    with pytest.raises(ValueError, match="cannot set the root attribute 'default'"):
        r.close({"default": "elsewhere"})


# -- NeXus done properly (issue 33): every setting in the entry, nothing a reader acts on ---------

# Metadata as the daemon gives it (camd.daemon.scan_apply, stream_service): the profile's values
# with their sources, the registers, the timing, the scan's or stream's settings, the scene in
# front of the camera and the campaign step that asked for the file.
REGISTERS = {"GAIN": 64, "OFFSET": 100, "WIN_ROWS": 6, "EXP_LO": 2}
SAMPLE = {"scene": "bars:period_px=8"}
ACTIVITY = {
    "text": "campaign mtf: step 3/12 acquire scan_m8",
    "done": 2,
    "total": 12,
    "set_utc": "2026-11-27T21:00:00.000+00:00",
}
COUNTS_PER_M = 1e6  # the stage encoder's counts per metre


def field_scan(path: Path, lines: int = 12, width: int = 16) -> np.ndarray:
    """A scan as the daemon writes one: every metadata group, the stage's encoder counts, the
    close's counters, motion and closed-loop record, the live view's background."""
    data = np.arange(lines * width, dtype=np.uint32).reshape(lines, width)
    r = TdiRecorder(
        path,
        width=width,
        mode="sum",
        metadata={
            "profile": PROFILE,
            "registers": REGISTERS,
            "timing": {"tdi_line_period_s": 250e-6, "exposure_s": 240e-6, "n_lines": 6,
                       "stage_speed_m_s": 0.01, "dv_over_v": 0.0},
            "scan": {"stages": 4, "lines": lines, "drive_stage": True, "mode": "sum"},
            "sample": SAMPLE,
            "activity": ACTIVITY,
        },
        background_dn=np.full((6, width), 100.0),
        background_attrs={"frames": 8, "mode": "area"},
    )  # fmt: skip
    r.append(data, index=np.arange(lines), stages_used=np.full(lines, 4),
             complete=np.ones(lines, bool), stage_position=2500 * np.arange(lines))  # fmt: skip
    r.close(
        {
            "counters": {"frames": lines, "lost": 0, "elapsed_s": 0.5, "mbyte_per_s": 1.5},
            "motion": {"closed_loop": "step_rate", "stage_speed_m_s": 0.01,
                       "encoder_counts_per_m": COUNTS_PER_M, "line_period_limited": False},
            "state": "done",
        },
        {"motion_loop": {"time_s": np.arange(3) * 0.1, "encoder_m": np.zeros(3)}},
    )  # fmt: skip
    return data


def field_stare(path: Path, n: int = 4) -> np.ndarray:
    """A stare as the daemon records one (metadata as ``field_scan``'s, the stream's)."""
    frames = np.arange(n * 3 * 5, dtype=np.uint16).reshape(n, 3, 5)
    rec = FrameRecorder(
        path,
        metadata={
            "profile": PROFILE,
            "registers": REGISTERS,
            "timing": {"exposure_s": 240e-6, "frame_period_s": 0.01, "readout_mode": "rolling"},
            "stream": {"frames_requested": n, "stages": 0, "binning": "off"},
            "sample": SAMPLE,
            "activity": ACTIVITY,
        },
        frames_expected=n,
    )
    for k, px in enumerate(frames):
        rec.add(header(k, px)._replace(stage_position=40 + 7 * k), px, received_ns=k)
    rec.close({"frames": n, "lost": 0, "elapsed_s": 0.04})
    return frames


# What nxcheck still reports: camd's own layout at the root, outside the entry, where a NeXus
# reader does not look (it follows NXroot's "default" to the entry): the datasets' root names
# (the same datasets as the entry's, kept for camd's readers, older tools and the repair) and
# the root attributes camd's readers and the repair read (format, finished, ...).
ROOT_DATASETS_SCAN = ["complete", "frame_counter", "line_index", "lines", "lines_flushed",
                      "m_dv_over_v", "stage_changes", "stage_position", "stages_used"]  # fmt: skip
ROOT_ATTRS_SCAN = ["camd_version", "complete_lines", "created_utc", "finished", "format",
                   "format_version", "lines", "mode", "state", "width"]  # fmt: skip
ROOT_DATASETS_STARE = ["flags", "frame_counter", "frames", "frames_flushed", "gap_before",
                       "payload_crc32", "received_unix_ns", "stage_position", "timestamp_ns"]  # fmt: skip
ROOT_ATTRS_STARE = ["bits", "camd_version", "cols", "created_utc", "finished", "format",
                    "format_version", "frames", "frames_expected", "line_period_s", "mode",
                    "rows"]  # fmt: skip


def _root_warnings(attrs: list[str], datasets: list[str]) -> list[str]:
    return [f'/: "@{a}" is not defined as an attribute in NXroot' for a in attrs] + [
        f"/{d}: This field is not defined in NXroot" for d in datasets
    ]


# The groups nxcheck inspects in both kinds of file (besides the entry's data and detector):
# every setting, the stage, the sample, the campaign step, camd's root attributes.
INSPECTED = [
    "NXcollection: /entry/camd",
    "NXcollection: /entry/profile",
    "NXcollection: /entry/registers",
    "NXparameters: /entry/timing",
    "NXpositioner: /entry/instrument/stage",
    "NXsample: /entry/sample",
    "NXnote: /entry/campaign_step",
]


# Each kind of file: how it is made, what nxcheck still reports of it, the groups of its own.
KINDS = {
    "scan": (field_scan, ROOT_ATTRS_SCAN, ROOT_DATASETS_SCAN, [
        "NXparameters: /entry/scan",
        "NXcollection: /entry/counters",
        "NXparameters: /entry/motion",
        "NXcollection: /entry/motion_loop",
        "NXcollection: /entry/background",
        "NXcollection: /entry/instrument/detector/tdi",
        "NXcollection: /entry/instrument/detector/per_line",
    ]),
    "stare": (field_stare, ROOT_ATTRS_STARE, ROOT_DATASETS_STARE, [
        "NXparameters: /entry/stream",
        "NXcollection: /entry/instrument/detector/per_frame",
    ]),
}  # fmt: skip


@pytest.mark.parametrize("kind", list(KINDS))
def test_nxcheck_finds_nothing_to_act_on(kind: str, tmp_path: Path) -> None:
    make, root_attrs, root_datasets, own_groups = KINDS[kind]
    make(tmp_path / "file.h5")
    found = nxcheck(tmp_path / "file.h5")
    assert found["error"] == []
    assert sorted(found["warning"]) == sorted(_root_warnings(root_attrs, root_datasets))
    # It inspected every group of the entry (nexusformat skips a group without NX_class).
    assert set(INSPECTED + own_groups) <= set(found["groups"])


def test_silx_finds_the_scan_an_image_and_the_stare_a_stack_of_images(tmp_path: Path) -> None:
    field_scan(tmp_path / "scan.h5")
    field_stare(tmp_path / "stare.h5")
    scan = silx_nxdata(tmp_path / "scan.h5")
    assert (scan["valid"], scan["issues"]) == (True, [])
    assert (scan["interpretation"], scan["is_image"]) == ("image", True)
    assert (scan["signal"], scan["signal_long_name"]) == ("lines", "lines (DN)")
    assert scan["axes_names"] == ["line_index", "column"]
    stare = silx_nxdata(tmp_path / "stare.h5")
    assert (stare["valid"], stare["issues"]) == (True, [])
    assert (stare["interpretation"], stare["is_image"], stare["signal_is_3d"]) == (
        "image", True, True,
    )  # fmt: skip
    assert stare["axes_names"] == ["frame_counter", "row", "column"]


def test_the_signal_and_every_setting_carry_their_units(tmp_path: Path) -> None:
    field_scan(tmp_path / "scan.h5")
    field_stare(tmp_path / "stare.h5")
    for name in ("scan.h5", "stare.h5"):
        p = nexus_plot(tmp_path / name)
        assert p["signal_attrs"]["units"] == "counts"
        assert p["signal_attrs"]["interpretation"] == "image"
    root = nxload(str(tmp_path / "scan.h5"), "r")
    try:
        entry = root["entry"]
        timing = entry["timing"]
        assert timing.nxclass == "NXparameters"
        assert (float(timing["exposure_s"]), timing["exposure_s"].attrs["units"]) == (240e-6, "s")
        assert timing["tdi_line_period_s"].attrs["units"] == "s"
        assert timing["stage_speed_m_s"].attrs["units"] == "m/s"
        assert "units" not in timing["n_lines"].attrs and "units" not in timing["dv_over_v"].attrs
        profile = entry["profile"]
        assert profile.nxclass == "NXcollection"
        # A described value (the profile's {"value", "source"}): the field, and where from.
        pitch = profile["pitch_m"]
        assert (float(pitch), pitch.attrs["units"], pitch.attrs["source"]) == (11e-6, "m", "YE23")
        # Register names are the camera's and their values codes: no units.
        registers = entry["registers"]
        assert registers.nxclass == "NXcollection" and int(registers["GAIN"]) == 64
        assert all("units" not in field.attrs for field in registers.values())
        assert entry["scan"].nxclass == "NXparameters" and int(entry["scan/stages"]) == 4
        counters = entry["counters"]
        assert counters["elapsed_s"].attrs["units"] == "s"
        assert counters["mbyte_per_s"].attrs["units"] == "MB/s"
        assert entry["motion"].nxclass == "NXparameters"
        assert entry["motion_loop/time_s"].attrs["units"] == "s"
        assert entry["background/mean_dn"].shape == (6, 16)
        # The stage: its encoder count at each line, and from it the position in metres.
        stage = entry["instrument/stage"]
        assert stage.nxclass == "NXpositioner"
        assert stage["raw_value"].nxvalue.tolist() == [2500 * k for k in range(12)]
        assert stage["raw_value"].attrs["units"] == "counts"
        assert stage["value"].attrs["units"] == "m"
        assert stage["value"].nxvalue == pytest.approx(2500e-6 * np.arange(12))
        assert (float(stage["velocity"]), stage["velocity"].attrs["units"]) == (0.01, "m/s")
        sample = entry["sample"]
        assert (sample.nxclass, sample["name"].nxvalue) == ("NXsample", "bars:period_px=8")
        note = entry["campaign_step"]
        assert note.nxclass == "NXnote"
        assert note["description"].nxvalue == ACTIVITY["text"]
        assert (int(note["sequence_index"]), note["date"].nxvalue) == (3, ACTIVITY["set_utc"])
        # The root's camd attributes, as the entry's fields (at the close's values).
        camd = entry["camd"]
        assert camd.nxclass == "NXcollection"
        assert (int(camd["format_version"]), int(camd["lines"]), bool(camd["finished"])) == (
            5, 12, True,
        )  # fmt: skip
    finally:
        root.nxfile.close()
    # camd's readers read the metadata groups as before, the new ones too.
    scan = read_tdi_scan(tmp_path / "scan.h5")
    assert scan.metadata["sample"] == SAMPLE and scan.metadata["activity"] == ACTIVITY
    assert read_recording(tmp_path / "stare.h5").metadata["sample"] == SAMPLE


def test_end_time_is_written_at_the_close_after_start_time(tmp_path: Path) -> None:
    field_scan(tmp_path / "scan.h5")
    field_stare(tmp_path / "stare.h5")
    FrameRecorder(tmp_path / "empty.h5", metadata={"profile": PROFILE}).close()
    for name in ("scan.h5", "stare.h5", "empty.h5"):
        with h5py.File(tmp_path / name, "r") as f:
            start = dt.datetime.fromisoformat(f["entry/start_time"][()].decode())
            end = dt.datetime.fromisoformat(f["entry/end_time"][()].decode())
            assert start <= end <= dt.datetime.now(dt.UTC), name
            assert start.isoformat(timespec="milliseconds") == f.attrs["created_utc"]


def test_the_root_paths_are_the_entrys_datasets(tmp_path: Path) -> None:
    data = field_scan(tmp_path / "scan.h5")
    frames = field_stare(tmp_path / "stare.h5")
    inside = {
        "scan.h5": {"lines": "entry/data/lines", "line_index": "entry/data/line_index",
                    "stage_position": "entry/instrument/stage/raw_value",
                    **{n: f"entry/instrument/detector/per_line/{n}" for n in ROOT_DATASETS_SCAN
                       if n != "lines"}},
        "stare.h5": {"frames": "entry/data/frames", "frame_counter": "entry/data/frame_counter",
                     "stage_position": "entry/instrument/stage/raw_value",
                     **{n: f"entry/instrument/detector/per_frame/{n}"
                        for n in ROOT_DATASETS_STARE if n != "frames"}},
    }  # fmt: skip
    for name, paths in inside.items():
        with h5py.File(tmp_path / name, "r") as f:
            for old, new in paths.items():
                # The same dataset (hard links: stored once, growing together while written).
                assert f[old].id == f[new].id, (name, old, new)
                assert np.array_equal(f[old][()], f[new][()], equal_nan=True), (name, old, new)
    with h5py.File(tmp_path / "scan.h5", "r") as f:
        assert np.array_equal(f["entry/data/lines"][()], data)
    with h5py.File(tmp_path / "stare.h5", "r") as f:
        assert np.array_equal(f["entry/data/frames"][()], frames)


def test_a_metadata_group_cannot_take_a_name_the_entry_holds(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="nor a name the entry holds \\(camd, campaign_step"):
        TdiRecorder(tmp_path / "a.h5", width=4, mode="sum", metadata={"instrument": {"x": 1}})
    with pytest.raises(RecordingError, match="'data' cannot be a metadata group of the recording"):
        FrameRecorder(tmp_path / "b.h5", metadata={"data": {"x": 1}})
    assert not (tmp_path / "a.h5").exists() and not (tmp_path / "b.h5").exists()


def test_files_of_the_first_nexus_formats_read_and_repair_as_before(tmp_path: Path) -> None:
    """A scan of format 4 and a recording of format 3 (the entry's data and detector only, the
    TDI settings as NXdetector fields): read as before; the repair of one whose writer died
    gives it an end_time and leaves the rest of its entry as it was."""
    data = field_scan(tmp_path / "scan.h5")
    frames = field_stare(tmp_path / "stare.h5")
    for name, version in (("scan.h5", 4), ("stare.h5", 3)):
        with h5py.File(tmp_path / name, "r+") as f:
            entry = f["entry"]
            for part in list(entry):
                if part not in ("data", "instrument", "title", "start_time", "program_name"):
                    del entry[part]
            del entry["instrument/stage"]
            detector = entry["instrument/detector"]
            for part in ("tdi", "per_line", "per_frame"):
                if part in detector:
                    del detector[part]
            if name == "scan.h5":
                detector["tdi_stages"], detector["tdi_mode"] = 4, "sum"
            for attr in ("file_time", "creator", "creator_version"):
                del f.attrs[attr]
            # As a dead writer left it: not finished (the repair's flags aside).
            f.attrs.update({"format_version": version, "finished": False})
    scan = read_tdi_scan(tmp_path / "scan.h5")
    assert np.array_equal(scan.lines, data) and scan.attrs["format_version"] == 4
    assert np.array_equal(read_recording(tmp_path / "stare.h5").frames, frames)
    for name in ("scan.h5", "stare.h5"):
        assert recover_file(tmp_path / name) is not None
        with h5py.File(tmp_path / name, "r") as f:
            start = dt.datetime.fromisoformat(f["entry/start_time"][()].decode())
            end = dt.datetime.fromisoformat(f["entry/end_time"][()].decode())
            assert start <= end
            assert f["entry/camd/interrupted"][()].decode() == f.attrs["interrupted"]
            assert f["entry/data"].attrs["signal"] in ("lines", "frames")
        assert recover_file(tmp_path / name) is not None  # again: still unfinished, the same
    with h5py.File(tmp_path / "scan.h5", "r") as f:  # its old detector as it was
        assert (f["entry/instrument/detector/tdi_stages"][()], f["lines"].shape) == (4, data.shape)
    assert np.array_equal(read_tdi_scan(tmp_path / "scan.h5").lines, data)
