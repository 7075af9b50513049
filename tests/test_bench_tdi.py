"""``camd bench tdi`` on tiny sizes: the document's shape and self-consistency, never its speed."""

from __future__ import annotations

import json
import statistics
from typing import Any

import pytest

from camd.cli.bench_tdi import (
    METHODS,
    ROUNDS,
    TARGETS,
    TdiMismatch,
    bench_tdi,
    naive_fractional,
    naive_weights,
    verify_engine,
)
from camd.cli.camd_main import main
from camd.tdi import TdiEngine, numba_available, tdi_batch

KERNELS = [
    "numpy",
    pytest.param("numba", marks=pytest.mark.skipif(not numba_available(), reason="no numba")),
]
SHAPES = ((8, 64), (5, 96))
PATH_KEYS = {
    "engine_gpix_s",
    "batch_gpix_s",
    "naive_gpix_s",
    "copy_gpix_s",
    "push_gpix_s",
    "engine_over_copy",
    "engine_over_naive",
    "batch_over_copy",
    "rows_per_line",
    "rows",
    "frames",
}


def _check_path(r: dict[str, Any], frames: int) -> None:
    assert r.keys() >= PATH_KEYS
    assert r["frames"] == frames
    for method in METHODS:
        rounds = r["rounds_gpix_s"][method]
        assert len(rounds) == ROUNDS and all(v > 0 for v in rounds)
        # The figure is the median of the rounds (which the document rounds to 3 decimals).
        assert r[f"{method}_gpix_s"] == pytest.approx(statistics.median(rounds), abs=6e-4)
    # Ratios are ratios of the medians.
    assert r["engine_over_copy"] == pytest.approx(r["engine_gpix_s"] / r["copy_gpix_s"])
    assert r["engine_over_naive"] == pytest.approx(r["engine_gpix_s"] / r["naive_gpix_s"])
    assert r["batch_over_copy"] == pytest.approx(r["batch_gpix_s"] / r["copy_gpix_s"])


@pytest.mark.parametrize("kernel", KERNELS)
def test_document_has_the_contract_keys_and_consistent_numbers(kernel: str) -> None:
    doc = bench_tdi(shapes=SHAPES, seconds=0.05, frames_mb=2, kernel=kernel)  # type: ignore[arg-type]
    assert doc["kernel"] == kernel
    assert (
        doc["targets"]
        == TARGETS
        == {
            "integer_engine_over_copy": 1.0,
            "fractional_engine_over_copy": 0.5,
            "integer_floor": 0.7,
        }
    )
    assert doc["threads"] >= 1 and "cpu" in doc and "numba" in doc
    assert [(s["stages"], s["width"]) for s in doc["shapes"]] == list(SHAPES)
    for s in doc["shapes"]:
        m = s["stages"]
        assert s["rows"] == s["integer"]["rows"] == m
        assert s["integer"]["rows_per_line"] == 1.0
        assert s["fractional"]["rows_per_line"] == 1.02
        # rows_needed of 1.02 rows per line: the last stage sits at (M - 1) * 1.02.
        assert s["fractional"]["rows"] == TdiEngine(m, s["width"], rows_per_line=1.02).rows_needed
        assert s["frames"] * s["fractional"]["rows"] * s["width"] * 2 <= 2e6
        _check_path(s["integer"], s["frames"])
        _check_path(s["fractional"], s["frames"])
        # The integer naive loop gives exactly the engine's sums.
        assert s["integer"]["naive_max_abs_diff_dn"] == 0
    # "met" follows from the figures and the targets (whatever they are on this machine).
    integer = [s["integer"]["engine_over_copy"] for s in doc["shapes"]]
    assert doc["met"]["integer_floor"] == (min(integer) >= 0.7)
    assert doc["met"]["integer_engine_over_copy"] == (min(integer) >= 1.0)


def test_cli_json_is_one_document(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["bench", "tdi", "--json", "--shapes", "6x80", "--frames-mb", "1", "--seconds", "0.05"]
    assert main([*argv, "--kernel", "numpy"]) == 0
    out = capsys.readouterr().out
    doc = json.loads(out)  # one document, nothing else on stdout
    assert doc["kernel"] == "numpy"
    assert [(s["stages"], s["width"]) for s in doc["shapes"]] == [(6, 80)]


def test_cli_human_says_whether_targets_are_met(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["bench", "tdi", "--shapes", "6x80", "--frames-mb", "1", "--seconds", "0.05"]
    assert main([*argv, "--kernel", "numpy"]) == 0
    out = capsys.readouterr().out
    assert "engine/copy >= 1 target:" in out
    assert "engine/copy >= 0.5 target:" in out
    assert "engine/copy >= 0.7 floor" in out


def test_cli_refuses_bad_options(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "tdi", "--seconds", "0"]) == 2
    with pytest.raises(SystemExit):
        main(["bench", "tdi", "--shapes", "96by2048"])
    capsys.readouterr()


def test_a_wrong_engine_is_caught_before_timing() -> None:
    # A real engine, wrongly configured (the scene moving the other way): same shapes, other
    # bits. The bench must refuse it rather than time it.
    def wrong(stages: int, width: int, **kw: Any) -> TdiEngine:
        return TdiEngine(stages, width, reverse=True, **kw)

    with pytest.raises(TdiMismatch, match="differs from tdi_batch"):
        bench_tdi(shapes=((6, 80),), seconds=0.05, frames_mb=1, kernel="numpy", make_engine=wrong)


def test_verify_engine_checks_push_as_well() -> None:
    import numpy as np

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


def test_naive_fractional_is_close_to_the_engine() -> None:
    import numpy as np

    frames = np.random.default_rng(2).integers(0, 4096, size=(30, 12, 40), dtype=np.uint16)
    ref, _ = tdi_batch(frames, 10, rows_per_line=1.02, kernel="numpy")
    got = naive_fractional(frames, 9, 21, naive_weights(10, 1.02, 12))
    assert np.abs(got.astype(np.int64) - ref[9:]).max() <= 1
