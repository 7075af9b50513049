"""What every ``camd bench`` shares: the machine, its last-level cache, and A/B alternation.

A benchmark here compares a subject with a baseline doing the same bare work in the same run
(bench/README.md says which baseline and why it is the fair one). Three rules make the
comparison like for like, and this module holds the code they need:

- inputs larger than the last-level cache, read from the machine (``beyond_cache_bytes``), so
  that neither side runs from a cache the other cannot use;
- baseline and subject alternated in rounds, A B then B A (``alternate``), so that a slow spell
  of a shared machine hits both, and the ratio is the median of the rounds' own ratios;
- rounds long enough to be stable (``MIN_ROUND_S``, whole passes until the time is spent).
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

MIN_ROUND_S = 2.0
"""The default length of one side's turn in a round: shorter turns let a slow spell of the
machine fall on one side only."""

DEFAULT_ROUNDS = 5
"""Rounds of an A/B alternation: an odd count, so the median is one of them."""


def add_round_options(parser: argparse.ArgumentParser, *, seconds: bool = True) -> None:
    """``--rounds`` (and ``--seconds``, a side's turn) of an A/B alternation."""
    if seconds:
        parser.add_argument(
            "--seconds",
            type=float,
            default=MIN_ROUND_S,
            help=f"length of each side's turn in a round (default {MIN_ROUND_S:g})",
        )
    parser.add_argument(
        "--rounds", type=int, default=DEFAULT_ROUNDS, help=f"rounds (default {DEFAULT_ROUNDS})"
    )


def int_list(text: str, what: str) -> tuple[int, ...]:
    """A comma-separated option value of whole numbers >= 1 (argparse's ``type``)."""
    try:
        values = tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        values = ()
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(
            f"{what} {text!r}: give whole numbers >= 1, comma-separated, e.g. 1,96"
        )
    return values


def choice_list(text: str, choices: Sequence[str], what: str) -> tuple[str, ...]:
    """A comma-separated option value of names from ``choices`` (argparse's ``type``)."""
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    unknown = [n for n in names if n not in choices]
    if unknown or not names:
        raise argparse.ArgumentTypeError(
            f"unknown {what} {', '.join(unknown) or repr(text)}: choose from {', '.join(choices)}"
        )
    return names


def last_level_cache_bytes() -> int | None:
    """The largest CPU cache this machine reports (Linux sysfs), or None."""
    sizes = []
    for index in Path("/sys/devices/system/cpu/cpu0/cache").glob("index*"):
        try:
            text = (index / "size").read_text().strip()
        except OSError:
            continue
        units = {"K": 1 << 10, "M": 1 << 20, "G": 1 << 30}
        if text and text[-1] in units and text[:-1].isdigit():
            sizes.append(int(text[:-1]) * units[text[-1]])
        elif text.isdigit():
            sizes.append(int(text))
    return max(sizes) if sizes else None


def beyond_cache_bytes(minimum_bytes: int, *, factor: int = 2) -> int:
    """A working-set size no cache of this machine holds: ``factor`` x its last-level cache,
    and at least ``minimum_bytes`` (also the answer when the cache size cannot be read)."""
    cache = last_level_cache_bytes()
    return max(minimum_bytes, factor * cache) if cache else minimum_bytes


def proc_status_int(pid: int, field: str) -> int | None:
    """The number of a ``/proc/PID/status`` field (``VmRSS`` and ``VmHWM`` in kB,
    ``Threads``), or None when it cannot be read (the process gone, not Linux)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text(encoding="utf-8").splitlines():
            key, _, value = line.partition(":")
            if key == field:
                return int(value.split()[0])
    except (OSError, ValueError, IndexError):
        return None
    return None


def thread_cpu_s(native_id: int) -> float:
    """User + system CPU seconds of one thread of this process (Linux /proc)."""
    fields = Path(f"/proc/self/task/{native_id}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``), else what ``platform`` says."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine() -> dict[str, Any]:
    """The machine a figure was measured on: CPU, cores, last-level cache, load average."""
    return {
        "cpu": cpu_model(),
        "cpus": os.cpu_count(),
        "last_level_cache_bytes": last_level_cache_bytes(),
        "loadavg": [round(x, 2) for x in os.getloadavg()],
    }


def rate_over(one_pass: Callable[[], float], seconds: float) -> float:
    """Run ``one_pass`` (which returns the units of work it did) until ``seconds`` have
    passed, in whole passes; units per second."""
    units = 0.0
    t0 = time.perf_counter()
    while True:
        units += one_pass()
        elapsed = time.perf_counter() - t0
        if elapsed >= seconds:
            return units / elapsed


@dataclass
class Alternation:
    """The rounds of an A/B alternation: the figure of each side in each round."""

    a: list[float] = field(default_factory=list)
    b: list[float] = field(default_factory=list)

    @property
    def ratios(self) -> list[float]:
        """B / A of each round (A and B measured back to back)."""
        return [b / a for a, b in zip(self.a, self.b, strict=True)]

    @property
    def ratio(self) -> float:
        """The median of the rounds' B / A."""
        return statistics.median(self.ratios)

    def summary(self, digits: int = 5) -> dict[str, Any]:
        """Medians of each side, the median ratio, its range and every round (to ``digits``
        significant digits)."""

        def sig(x: float) -> float:
            return float(f"{x:.{digits}g}")

        ratios = self.ratios
        return {
            "a": sig(statistics.median(self.a)),
            "b": sig(statistics.median(self.b)),
            "ratio": sig(self.ratio),
            "ratio_range": [sig(min(ratios)), sig(max(ratios))],
            "rounds_a": [sig(x) for x in self.a],
            "rounds_b": [sig(x) for x in self.b],
        }


def alternate(
    measure_a: Callable[[], float], measure_b: Callable[[], float], rounds: int
) -> Alternation:
    """``rounds`` rounds of A and B, A B in even rounds and B A in odd ones (so neither side
    always goes first, after the other has warmed or cooled the machine)."""
    if rounds < 1:
        raise ValueError(f"rounds = {rounds}: give at least 1")
    result = Alternation()
    for r in range(rounds):
        if r % 2 == 0:
            result.a.append(measure_a())
            result.b.append(measure_b())
        else:
            result.b.append(measure_b())
            result.a.append(measure_a())
    return result


def window_rows_range(profile: str) -> tuple[int, int]:
    """The fewest window rows the sensor's map allows (a rows-minus-1 field's minimum counts
    its bias) and the sensor's rows."""
    from camd.sensor.profile import load_profile
    from camd.sensor.regmap import load_register_map

    most = int(load_profile(profile).rows.value)
    regmap = load_register_map(profile)
    name = regmap.role("window_rows")
    field = regmap.resolve(name)[1] if name is not None else None
    fewest = field.count(field.lo) if field is not None else 1
    return max(1, fewest), most


def window_stages(profile: str, stages: Sequence[int]) -> list[int]:
    """The window rows to run each M of ``stages`` at on ``profile``, in order, each once: M
    raised to the sensor's fewest window rows and capped at its rows (``window_rows_range``)."""
    fewest, most = window_rows_range(profile)
    return sorted({min(max(m, fewest), most) for m in stages})
