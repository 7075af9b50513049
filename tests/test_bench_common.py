"""The benchmarks' shared rules: A/B alternation, ratios of rounds, working sets beyond cache."""

from __future__ import annotations

import argparse
import itertools

import pytest

from camd.bench import common as bench_common
from camd.bench.common import Alternation, alternate, beyond_cache_bytes, rate_over


def test_alternation_swaps_the_order_every_round() -> None:
    calls: list[str] = []
    counter = itertools.count(1)

    def side(name: str) -> float:
        calls.append(name)
        return float(next(counter))

    result = alternate(lambda: side("a"), lambda: side("b"), rounds=4)
    assert calls == ["a", "b", "b", "a", "a", "b", "b", "a"]
    # Each round's figures are its own, whichever went first.
    assert result.a == [1.0, 4.0, 5.0, 8.0] and result.b == [2.0, 3.0, 6.0, 7.0]


def test_the_ratio_is_the_median_of_the_rounds_ratios() -> None:
    r = Alternation(a=[1.0, 2.0, 4.0], b=[2.0, 2.0, 2.0])
    assert r.ratios == [2.0, 1.0, 0.5]
    assert r.ratio == 1.0  # the ratio of the medians (2 / 2) happens to agree here ...
    skew = Alternation(a=[1.0, 10.0, 10.0], b=[3.0, 10.0, 30.0])
    assert skew.ratio == 3.0  # ... but not here: median(3, 1, 3) against median 10 / 10
    s = skew.summary()
    assert s["a"] == 10.0 and s["b"] == 10.0 and s["ratio"] == 3.0
    assert s["ratio_range"] == [1.0, 3.0]
    assert s["rounds_a"] == [1.0, 10.0, 10.0]


def test_alternate_needs_a_round() -> None:
    with pytest.raises(ValueError, match="rounds = 0: give at least 1"):
        alternate(lambda: 1.0, lambda: 1.0, rounds=0)


def test_rate_over_runs_whole_passes_until_the_time_is_spent() -> None:
    passes = []

    def one_pass() -> float:
        passes.append(1)
        return 5.0

    rate = rate_over(one_pass, 0.01)
    assert len(passes) >= 1 and rate > 0
    # units / elapsed, with elapsed >= the time asked for
    assert rate <= 5.0 * len(passes) / 0.01


def test_beyond_cache_reads_the_machine(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(bench_common, "last_level_cache_bytes", lambda: 32 << 20)
    assert beyond_cache_bytes(1 << 20) == 64 << 20
    assert beyond_cache_bytes(256 << 20) == 256 << 20
    assert beyond_cache_bytes(1 << 20, factor=4) == 128 << 20
    monkeypatch.setattr(bench_common, "last_level_cache_bytes", lambda: None)
    assert beyond_cache_bytes(7) == 7


def test_the_machine_is_described() -> None:
    m = bench_common.machine()
    assert m["cpus"] >= 1 and len(m["loadavg"]) == 3 and m["cpu"]
    cache = m["last_level_cache_bytes"]
    assert cache is None or cache >= 1 << 16


def test_proc_status_reads_this_process() -> None:
    import os

    pid = os.getpid()
    # Threads, against the kernel's own list of this process's tasks.
    assert bench_common.proc_status_int(pid, "Threads") == len(os.listdir(f"/proc/{pid}/task"))
    rss = bench_common.proc_status_int(pid, "VmRSS")
    peak = bench_common.proc_status_int(pid, "VmHWM")
    assert rss is not None and peak is not None and 0 < rss <= peak
    assert bench_common.proc_status_int(pid, "NoSuchField") is None
    assert bench_common.proc_status_int(2**22 + 12345, "VmRSS") is None  # no such process


def test_int_list_takes_whole_numbers_and_says_what_to_give() -> None:
    assert bench_common.int_list("1,96", "--stages") == (1, 96)
    assert bench_common.int_list(" 8 , 32 ,", "--stages") == (8, 32)
    for bad in ("0,96", "x", "", "1.5"):
        with pytest.raises(argparse.ArgumentTypeError, match="give whole numbers >= 1"):
            bench_common.int_list(bad, "--stages")
