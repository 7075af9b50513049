"""``camd bench all``: every benchmark in its own process, one document of ratios (tiny runs)."""

from __future__ import annotations

import json

import pytest

from camd.bench import run_all as bench_all
from camd.bench.run_all import BENCHES, NAMES, Bench, four_figures, run_one
from camd.cli.camd_main import main

TINY_TDI = ("--shapes", "6x64", "--frames-mb", "1", "--seconds", "0.02", "--rounds", "1")


def test_every_benchmark_is_in_the_set() -> None:
    assert NAMES == (
        "ping", "stream", "tdi", "sim", "pipeline", "scan", "live", "motion", "store", "fuzz"
    )  # fmt: skip
    # Each has a parser: `camd bench NAME --help` exits 0.
    for name in NAMES:
        with pytest.raises(SystemExit) as exc:
            main(["bench", name, "--help"])
        assert exc.value.code == 0


def test_one_benchmark_in_its_own_process_gives_its_ratios() -> None:
    tdi = next(b for b in BENCHES if b.name == "tdi")
    entry = run_one(
        Bench("tdi", (*TINY_TDI, "--paths", "integer,push"), (), tdi.figures), quick=False
    )
    assert entry["exit_status"] == 0, entry
    doc = entry["doc"]
    paths = doc["shapes"][0]["paths"]
    assert entry["ratios"] == {
        "tdi 6x64 integer engine/copy": paths["integer"]["over_copy"],
        "tdi 6x64 push engine/copy": paths["push"]["over_copy"],
    }
    assert entry["argv"][:4] == ["camd", "bench", "tdi", "--json"]


def test_a_failing_benchmark_is_reported_and_the_rest_still_run(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    tdi = next(b for b in BENCHES if b.name == "tdi")
    ping = next(b for b in BENCHES if b.name == "ping")
    monkeypatch.setattr(
        bench_all,
        "BENCHES",
        (
            Bench("ping", ("--count", "5"), (), ping.figures),  # refused: exit status 2
            Bench("tdi", (*TINY_TDI, "--paths", "drift"), (), tdi.figures),
        ),
    )
    assert main(["bench", "all", "--json", "--only", "ping,tdi"]) == 1
    doc = json.loads(capsys.readouterr().out)
    assert doc["failed"] == ["ping"]
    assert doc["benches"]["ping"]["exit_status"] == 2
    assert "--count 0 (by time) or at least 10 per round" in doc["benches"]["ping"]["error"]
    assert list(doc["ratios"]) == ["tdi 6x64 drift engine/copy"]
    assert doc["ratios"]["tdi 6x64 drift engine/copy"] == pytest.approx(
        doc["benches"]["tdi"]["doc"]["shapes"][0]["paths"]["drift"]["over_copy"], rel=1e-3
    )
    assert doc["machine"]["cpus"] >= 1 and doc["quick"] is False


def test_names_are_checked(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["bench", "all", "--only", "tdi,warp"])
    assert "unknown benchmark warp: choose from ping, stream, tdi" in capsys.readouterr().err
    assert main(["bench", "all", "--only", "tdi", "--skip", "tdi"]) == 2
    assert "leave no benchmark to run" in capsys.readouterr().err


def test_the_summary_keeps_four_significant_figures_of_a_small_ratio() -> None:
    assert four_figures(0.00098103) == 0.000981
    assert four_figures(123.456) == 123.5
    assert four_figures(1.0) == 1.0
