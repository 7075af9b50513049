"""Training the simulated LVDS link as the FPGA does (``train``): each lane's data eye scanned
over its input-delay taps and the tap put at the eye's centre, the word found by bit-slip
against the training word, the lanes' latencies matched on the frame-sync marker; and checking
a trained link with a known pattern (``verify``, ``bit_errors``). The link itself, its lanes'
skews and the patterns are in ``firmware_models.lvds``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from firmware_models.lvds import (
    DEFAULT_MARKER_PERIOD,
    DEFAULT_MIN_EYE_TAPS,
    DEFAULT_TRAINING_WORD,
    Alignment,
    LvdsLink,
    Words,
    _mask,
    check_training_word,
    default_marker_word,
    frame_to_lanes,
    prbs_frame,
    rotations,
    training_frame,
)

# -- training -------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class LaneTraining:
    """What training found on one lane. ``eye``: one char per tap, '-' stable, 'x' not."""

    lane: int
    tap: int
    eye_width_taps: int
    slips: int
    shift: int
    locked: bool
    eye: str = ""
    arrival_words: int = -1  # words after readout start at which the lane's marker arrived
    reason: str = ""  # why the lane did not lock ("" when locked)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready copy."""
        return {
            "lane": self.lane,
            "tap": self.tap,
            "eye_width_taps": self.eye_width_taps,
            "slips": self.slips,
            "shift": self.shift,
            "locked": self.locked,
            "eye": self.eye,
            "arrival_words": self.arrival_words,
            "reason": self.reason,
        }


@dataclass(frozen=True, slots=True)
class TrainingResult:
    """The outcome of :func:`train`: settings to load and a per-lane report."""

    alignment: Alignment
    lanes: list[LaneTraining] = field(default_factory=list)

    @property
    def locked(self) -> bool:
        """True when every lane locked."""
        return bool(self.lanes) and all(lane.locked for lane in self.lanes)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready report (what TRAIN returns)."""
        return {
            "locked": self.locked,
            "latency": self.alignment.latency,
            "lanes": [lane.to_dict() for lane in self.lanes],
            "alignment": self.alignment.to_dict(),
        }


def train(
    link: LvdsLink,
    training_word: int = DEFAULT_TRAINING_WORD,
    *,
    rng_seed: int = 0,
    marker_word: int | None = None,
    marker_period: int = DEFAULT_MARKER_PERIOD,
    words_per_lane: int = 128,
    repeats: int = 3,
    min_eye_taps: int = DEFAULT_MIN_EYE_TAPS,
) -> TrainingResult:
    """Train the link as the FPGA does, seeing only what the deserialisers output.

    With the sensor sending :func:`training_frame`:

    1. bit alignment: for each tap capture ``repeats`` times; a tap is stable on a lane if every
       capture is identical and its commonest word is a rotation of the training word; the lane's
       tap is the centre of its widest (circular) run of stable taps;
    2. word alignment: at that tap, the bit-slip at which most captured words equal the training
       word (it must be at least half of them);
    3. channel alignment: the marker is sent on all lanes at once, so the lane word at which it
       arrives is the lane's latency; early lanes are shifted to match the latest, which becomes
       the common latency.

    A lane with no stable window, no matching slip or no marker is reported not locked and left
    at zero settings. Never reads ``link.skews``.
    """
    check_training_word(training_word, link.word_bits)
    marker = (
        default_marker_word(training_word, link.word_bits) if marker_word is None else marker_word
    )
    if marker_period <= link.max_word_latency + 2:
        # A lane can be up to max_word_latency words + 2 bits late; the marker must not alias.
        raise ValueError(f"marker period {marker_period} too short for the link's latency range")
    lanes = link.lanes
    pattern = training_frame(
        1,
        lanes * words_per_lane,
        training_word,
        lanes=lanes,
        word_bits=link.word_bits,
        marker_word=marker,
        marker_period=marker_period,
    )
    rng = np.random.default_rng(rng_seed)

    def capture(alignment: Alignment) -> Words:
        got = link.receive(pattern, alignment, idle_word=training_word, rng=rng)
        return frame_to_lanes(got, lanes)

    stable = _scan_eye(link, capture, training_word, repeats)
    reports: list[dict[str, Any]] = []
    for lane in range(lanes):
        tap, width = _eye_centre(stable[:, lane])
        eye = "".join("-" if s else "x" for s in stable[:, lane])
        ok = width >= min_eye_taps
        reports.append(
            {
                "lane": lane,
                "tap": tap if ok else 0,
                "eye_width_taps": width,
                "eye": eye,
                "locked": ok,
                "reason": "" if ok else f"no stable eye (widest window {width} taps)",
            }
        )
    taps = [r["tap"] for r in reports]

    # Word alignment: try every slip at once on all lanes.
    n_words = frame_to_lanes(pattern, lanes).shape[1]
    matches = np.zeros((link.word_bits, lanes), dtype=np.int64)
    for slip in range(link.word_bits):
        got = capture(Alignment(taps=taps, slips=[slip] * lanes, shifts=[0] * lanes))
        matches[slip] = (got == training_word).sum(axis=1)
    for lane, rep in enumerate(reports):
        best = int(np.argmax(matches[:, lane]))
        rep["slips"] = best if rep["locked"] else 0
        if rep["locked"] and 2 * int(matches[best, lane]) < n_words:
            rep.update(locked=False, slips=0, reason="no bit-slip reproduces the training word")
    slips = [r["slips"] for r in reports]

    # Channel alignment: where does the marker arrive on each lane?
    got = capture(Alignment(taps=taps, slips=slips, shifts=[0] * lanes))
    for lane, rep in enumerate(reports):
        hits = np.flatnonzero(got[lane] == marker)
        rep["arrival_words"] = int(hits[0]) if hits.size and rep["locked"] else -1
        if rep["locked"] and rep["arrival_words"] < 0:
            rep.update(locked=False, reason="frame-sync marker not seen")
    arrivals = [r["arrival_words"] for r in reports if r["locked"]]
    latency = max(arrivals, default=0)
    for rep in reports:
        rep["shift"] = latency - rep["arrival_words"] if rep["locked"] else 0
        if not rep["locked"]:
            rep.update(tap=0, slips=0)

    lane_reports = [LaneTraining(**rep) for rep in reports]
    locked = all(r.locked for r in lane_reports)
    alignment = Alignment(
        taps=[r.tap for r in lane_reports],
        slips=[r.slips for r in lane_reports],
        shifts=[r.shift for r in lane_reports],
        latency=latency,
        trained=locked,
    )
    return TrainingResult(alignment=alignment, lanes=lane_reports)


def _scan_eye(
    link: LvdsLink, capture: Callable[[Alignment], Words], training_word: int, repeats: int
) -> npt.NDArray[np.bool_]:
    """(taps_per_ui, lanes) booleans: the lane's captures are stable at that tap."""
    lanes = link.lanes
    good_words = np.zeros(_mask(link.word_bits) + 1, dtype=bool)
    good_words[[training_word, *rotations(training_word, link.word_bits)]] = True
    stable = np.zeros((link.taps_per_ui, lanes), dtype=bool)
    for tap in range(link.taps_per_ui):
        alignment = Alignment(taps=[tap] * lanes, slips=[0] * lanes, shifts=[0] * lanes)
        shots = np.stack([capture(alignment) for _ in range(max(2, repeats))])
        same = (shots == shots[0]).all(axis=(0, 2))
        for lane in range(lanes):
            if same[lane]:
                commonest = int(np.bincount(shots[0, lane]).argmax())
                stable[tap, lane] = bool(good_words[commonest])
    return stable


def _eye_centre(stable: npt.NDArray[np.bool_]) -> tuple[int, int]:
    """(centre tap, width) of the widest circular run of True; (0, 0) if there is none."""
    period = stable.size
    if stable.all():
        return period // 2, period
    if not stable.any():
        return 0, 0
    # Start scanning just after an unstable tap so no run is split by the wrap-around.
    start = int(np.flatnonzero(~stable)[0]) + 1
    best_start, best_len, run_start, run_len = 0, 0, 0, 0
    for k in range(period):
        tap = (start + k) % period
        if stable[tap]:
            if run_len == 0:
                run_start = tap
            run_len += 1
            if run_len > best_len:
                best_start, best_len = run_start, run_len
        else:
            run_len = 0
    return (best_start + best_len // 2) % period, best_len


# -- end-to-end check -----------------------------------------------------------------------------


def bit_errors(sent: npt.NDArray[Any], got: npt.NDArray[Any]) -> int:
    """Number of differing bits between two word arrays of the same shape."""
    diff = np.bitwise_xor(np.asarray(sent, dtype=np.uint16), np.asarray(got, dtype=np.uint16))
    return int(np.bitwise_count(diff).sum())


def verify(
    link: LvdsLink, alignment: Alignment, rows: int = 16, cols: int = 2048, *, seed: int = 1
) -> int:
    """Send a PRBS test frame over the link and count bit errors in what the FPGA captures."""
    sent = prbs_frame(rows, cols, link.word_bits, seed)
    return bit_errors(sent, link.receive(sent, alignment))
