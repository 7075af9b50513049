"""``camd bench tdi`` on tiny sizes: the document's shape and self-consistency, never its speed."""

from __future__ import annotations

import json
import statistics
from typing import Any

import numpy as np
import pytest

from camd.bench.tdi import (
    PATHS,
    PUSH_FRAMES,
    TARGETS,
    TdiMismatch,
    bench_tdi,
    frame_set_bytes,
    verify_engine,
)
from camd.cli.camd_main import main
from camd.pipeline.batcher import batch_frames_for
from camd.tdi import TdiEngine, numba_available

KERNELS = [
    "numpy",
    pytest.param("numba", marks=pytest.mark.skipif(not numba_available(), reason="no numba")),
]
SHAPES = ((8, 64), (5, 96))
ROUNDS = 3


def _check_path(r: dict[str, Any], path: str, stages: int, width: int) -> None:
    spec = PATHS[path]
    assert r["rows_per_line"] == spec.rows_per_line
    assert r["cols_per_line"] == spec.cols_per_line
    rows = TdiEngine(
        stages, width, rows_per_line=spec.rows_per_line, cols_per_line=spec.cols_per_line
    ).rows_needed
    assert r["rows"] == rows
    # At least 2 M frames (lines with every stage) and a push pass's worth.
    assert r["frames"] >= max(2 * stages, PUSH_FRAMES)
    assert r["block"] == (1 if spec.one_frame_per_call else batch_frames_for(rows, width))
    assert r["subject"] == ("push" if spec.one_frame_per_call else "push_many")
    copies, engines = r["rounds_copy_gpix_s"], r["rounds_engine_gpix_s"]
    assert len(copies) == len(engines) == ROUNDS and min(copies + engines) > 0
    assert r["copy_gpix_s"] == pytest.approx(statistics.median(copies), rel=1e-4)
    assert r["engine_gpix_s"] == pytest.approx(statistics.median(engines), rel=1e-4)
    # The ratio is the median of the rounds' own ratios (A and B back to back), not a ratio of
    # medians; the range is theirs too.
    ratios = [e / c for c, e in zip(copies, engines, strict=True)]
    assert r["over_copy"] == pytest.approx(statistics.median(ratios), rel=2e-3)
    assert r["over_copy_range"] == pytest.approx([min(ratios), max(ratios)], rel=2e-3)
    assert r["target"] == TARGETS[path]
    assert r["met"] == (r["over_copy"] >= TARGETS[path])


@pytest.mark.parametrize("kernel", KERNELS)
def test_document_has_every_path_and_consistent_numbers(kernel: str) -> None:
    doc = bench_tdi(shapes=SHAPES, seconds=0.02, rounds=ROUNDS, frames_mb=2, kernel=kernel)  # type: ignore[arg-type]
    assert doc["kernel"] == kernel
    assert (
        doc["targets"] == TARGETS == {"integer": 1.3, "fractional": 0.8, "drift": 0.7, "push": 0.9}
    )
    assert doc["frame_set_bytes"] == 2_000_000
    assert {"cpu", "cpus", "last_level_cache_bytes", "loadavg"} <= doc["machine"].keys()
    assert [(s["stages"], s["width"]) for s in doc["shapes"]] == list(SHAPES)
    for s in doc["shapes"]:
        assert list(s["paths"]) == ["integer", "fractional", "drift", "push"]
        for path, r in s["paths"].items():
            _check_path(r, path, s["stages"], s["width"])
    # "met" per path follows from every shape's figure.
    for path in PATHS:
        assert doc["met"][path] == all(s["paths"][path]["met"] for s in doc["shapes"])


def test_the_frame_set_is_beyond_the_cache_unless_sized() -> None:
    from camd.bench.common import last_level_cache_bytes

    assert frame_set_bytes(3.5) == 3_500_000
    cache = last_level_cache_bytes()
    assert frame_set_bytes(0) == max(256 << 20, 2 * cache if cache else 0)


def test_cli_json_is_one_document(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["bench", "tdi", "--json", "--shapes", "6x80", "--frames-mb", "1", "--seconds", "0.02"]
    assert main([*argv, "--rounds", "1", "--paths", "push,drift", "--kernel", "numpy"]) == 0
    out = capsys.readouterr().out
    doc = json.loads(out)  # one document, nothing else on stdout
    assert doc["kernel"] == "numpy"
    assert [(s["stages"], s["width"]) for s in doc["shapes"]] == [(6, 80)]
    assert list(doc["shapes"][0]["paths"]) == ["push", "drift"]


def test_cli_human_says_whether_goals_are_met(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["bench", "tdi", "--shapes", "6x80", "--frames-mb", "1", "--seconds", "0.02"]
    assert main([*argv, "--rounds", "1", "--kernel", "numpy"]) == 0
    out = capsys.readouterr().out
    for path, goal in (("integer", ">= 1.3"), ("fractional", ">= 0.8"), ("drift", ">= 0.7")):
        line = next(x for x in out.splitlines() if f" {path} " in x)
        assert goal in line and ("met" in line)
    assert "checked against tdi_batch" in out


def test_cli_refuses_bad_options(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "tdi", "--seconds", "0"]) == 2
    assert main(["bench", "tdi", "--rounds", "0"]) == 2
    assert "--rounds >= 1" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["bench", "tdi", "--shapes", "96by2048"])
    with pytest.raises(SystemExit):
        main(["bench", "tdi", "--paths", "integer,diagonal"])
    assert "unknown path diagonal: choose from integer, fractional, drift, push" in (
        capsys.readouterr().err
    )


def test_a_wrong_engine_is_caught_before_timing() -> None:
    # A real engine, wrongly configured (the scene moving the other way): same shapes, other
    # bits. The bench must refuse it rather than time it.
    def wrong(stages: int, width: int, **kw: Any) -> TdiEngine:
        return TdiEngine(stages, width, reverse=True, **kw)

    with pytest.raises(TdiMismatch, match="differs from tdi_batch"):
        bench_tdi(
            shapes=((6, 80),),
            seconds=0.02,
            rounds=1,
            frames_mb=1,
            kernel="numpy",
            make_engine=wrong,
        )


def test_verify_engine_checks_push_as_well() -> None:
    frames = np.random.default_rng(1).integers(0, 4096, size=(40, 6, 32), dtype=np.uint16)
    good = TdiEngine(6, 32, kernel="numpy")
    verify_engine(good, TdiEngine(6, 32, kernel="numpy"), frames, 7, "ok", stages=6, kernel="numpy")
    with pytest.raises(TdiMismatch, match=r"push\(\) differs"):
        verify_engine(
            TdiEngine(6, 32, kernel="numpy"),
            TdiEngine(6, 32, kernel="numpy", reverse=True),
            frames,
            7,
            "push",
            stages=6,
            kernel="numpy",
        )
