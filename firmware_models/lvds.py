"""LVDS link between the HR400-class sensor and the FPGA, and the FPGA's link training.

docs/physics.md §3: image data arrive on 8 LVDS data lanes plus a DDR clock lane; before imaging the
FPGA trains the link (bit alignment at the centre of the data eye, word alignment by bit-slip,
channel alignment by lane shift). This module models the link closely enough that training is
needed and has to be done the way an FPGA does it. See docs/lvds.md.

Lane mapping: pixel column ``j`` travels on lane ``j % lanes``; each lane sends its pixels row by
row (row 0: columns ``l, l + lanes, ...``; then row 1; ...), every word MSB first. The frame's
first word leaves all lanes at the same word instant 0 of the FPGA's word clock (the FPGA drives
the sensor's sequencer, so it knows that instant). Before and after the frame a lane carries its
idle word.

Skew of lane ``l`` (random per seed, redrawn on a power cycle):

- ``delay_taps``: sub-bit delay of the data relative to the sampling clock, in input-delay taps
  (``taps_per_ui`` per bit period). The FPGA's tap adds to it: ``D = delay_taps + tap``.
- ``bit_offset``: whole bits of delay (0 .. word_bits - 1), so word boundaries are unknown.
- ``word_latency``: whole words of delay (0 .. max_word_latency), so lanes are out of step.

The FPGA samples at its clock edges. A sample lands at ``r = (-D) mod taps_per_ui`` taps after
the start of a data bit; within ``jitter_taps`` of a transition (``r < J`` or ``P - r < J``) the
flip-flop sees either neighbour at random (a random bit wherever the two neighbouring bits
differ). The eye is therefore ``P - 2J + 1`` taps wide. In whole bits the lane is late by
``delta = word_latency * word_bits + bit_offset + ceil(D / P)``.

The FPGA deserialiser of each lane has an input-delay ``tap``, a bit-``slip`` (where a word
starts in the bit stream) and a lane ``shift`` (words of FIFO delay); ``latency`` (common to all
lanes) is the words from readout start to the first word the FPGA keeps. Output word ``m`` of a
lane therefore starts at sampled bit ``(m + latency - shift) * word_bits + slip``, which is
transmitted bit ``(m + latency - shift) * word_bits + slip - delta``. Trained settings make that
``m * word_bits``: bit-exact.

Everything is vectorised per lane at word level (a word straddling two transmitted words is two
shifts and an or), so a 534 x 2048 window frame takes a few milliseconds.
"""

from __future__ import annotations

import enum
from collections.abc import Collection, Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
import numpy.typing as npt

Words = npt.NDArray[np.uint16]

HR400_LANES = 8
HR400_WORD_BITS = 12
DEFAULT_TAPS_PER_UI = 32  # IDELAY-class input delay: 32 taps span one bit period
DEFAULT_JITTER_TAPS = 3
DEFAULT_MAX_WORD_LATENCY = 3
DEFAULT_TRAINING_WORD = 0x03F  # 0b000000111111: one rising and one falling edge per word
DEFAULT_MARKER_WORD = 0xA5A  # frame-sync marker of the training pattern (not a rotation of 0x03F)
DEFAULT_MARKER_PERIOD = 16  # lane words between markers; must exceed any lane's latency in words
DEFAULT_MIN_EYE_TAPS = 3

_SKEW_STREAM = 0x4C53  # "LS": the skew draw and the metastability noise are independent streams
_NOISE_STREAM = 0x4C4E  # "LN"


@dataclass(frozen=True, slots=True)
class LaneSkew:
    """How late one lane's data arrive: sub-bit taps, whole bits, whole words."""

    delay_taps: int
    bit_offset: int
    word_latency: int


@dataclass(slots=True)
class Alignment:
    """The FPGA deserialiser settings, one entry per lane, plus the common frame latency."""

    taps: list[int]
    slips: list[int]
    shifts: list[int]
    latency: int = 0
    trained: bool = False

    @classmethod
    def untrained(cls, lanes: int = HR400_LANES) -> Alignment:
        """The reset state of the deserialisers: every tap, slip and shift zero."""
        return cls(taps=[0] * lanes, slips=[0] * lanes, shifts=[0] * lanes)

    @property
    def lanes(self) -> int:
        """Number of lanes these settings are for."""
        return len(self.taps)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready copy of the settings."""
        return {
            "taps": list(self.taps),
            "slips": list(self.slips),
            "shifts": list(self.shifts),
            "latency": self.latency,
            "trained": self.trained,
        }


class TestPattern(enum.IntEnum):
    """Values of the sensor's TEST_PATTERN register (what the sensor sends instead of pixels)."""

    __test__ = False  # not a pytest test class despite the name

    OFF = 0
    TRAINING = 1
    RAMP = 2
    PRBS = 3


# -- words, rotations, lane mapping -------------------------------------------------------------


def _mask(word_bits: int) -> int:
    return (1 << word_bits) - 1


def rotations(word: int, word_bits: int) -> set[int]:
    """Every non-trivial rotation of ``word`` (what a misaligned word boundary turns it into)."""
    mask = _mask(word_bits)
    return {((word << k) | (word >> (word_bits - k))) & mask for k in range(1, word_bits)}


def check_training_word(word: int, word_bits: int = HR400_WORD_BITS) -> None:
    """Raise ValueError unless ``word`` fits ``word_bits`` and differs from all its rotations.

    A word equal to one of its rotations (0x000, 0xFFF, 0x555, 0x249, ...) reads the same at
    several bit-slip positions, so word alignment could lock on the wrong boundary.
    """
    if not 0 <= word <= _mask(word_bits):
        raise ValueError(
            f"training word 0x{word:X} does not fit in {word_bits} bits "
            f"(0x000 .. 0x{_mask(word_bits):X})"
        )
    same = sorted(k for k in range(1, word_bits) if _rotate(word, k, word_bits) == word)
    if same:
        raise ValueError(
            f"training word 0x{word:0{(word_bits + 3) // 4}X} equals its own rotation by {same[0]} "
            f"bit(s), so bit-slip cannot find the word boundary; use a word that differs from all "
            f"its rotations, e.g. 0x{DEFAULT_TRAINING_WORD:03X}"
        )


def _rotate(word: int, k: int, word_bits: int) -> int:
    return ((word << k) | (word >> (word_bits - k))) & _mask(word_bits)


def default_marker_word(training_word: int, word_bits: int = HR400_WORD_BITS) -> int:
    """The frame-sync marker to pair with ``training_word``: 0xA5A unless that clashes."""
    mask = _mask(word_bits)
    taken = rotations(training_word, word_bits) | {training_word}
    for offset in range(mask + 1):
        candidate = (DEFAULT_MARKER_WORD + offset) & mask
        if candidate not in taken:
            return candidate
    raise ValueError(f"no marker word available for {word_bits}-bit words")  # pragma: no cover


def frame_to_lanes(frame: npt.NDArray[Any], lanes: int = HR400_LANES) -> Words:
    """Split a (rows, cols) frame into (lanes, rows * cols / lanes) lane streams, in send order."""
    rows, cols = _frame_shape(frame, lanes)
    per_row = cols // lanes
    streams = np.asarray(frame, dtype=np.uint16).reshape(rows, per_row, lanes)
    return np.ascontiguousarray(streams.transpose(2, 0, 1).reshape(lanes, rows * per_row))


def lanes_to_frame(streams: npt.NDArray[Any], rows: int, cols: int) -> Words:
    """Inverse of :func:`frame_to_lanes`."""
    lanes = streams.shape[0]
    per_row = cols // lanes
    frame = np.asarray(streams, dtype=np.uint16).reshape(lanes, rows, per_row)
    return np.ascontiguousarray(frame.transpose(1, 2, 0).reshape(rows, cols))


def _frame_shape(frame: npt.NDArray[Any], lanes: int) -> tuple[int, int]:
    if frame.ndim != 2:
        raise ValueError(f"frame must be 2-D (rows, cols), got shape {frame.shape}")
    rows, cols = int(frame.shape[0]), int(frame.shape[1])
    if cols % lanes:
        raise ValueError(f"frame width {cols} is not a multiple of the {lanes} LVDS lanes")
    return rows, cols


# -- test patterns the sensor can send ------------------------------------------------------------


def training_frame(
    rows: int,
    cols: int,
    training_word: int = DEFAULT_TRAINING_WORD,
    *,
    lanes: int = HR400_LANES,
    word_bits: int = HR400_WORD_BITS,
    marker_word: int | None = None,
    marker_period: int = DEFAULT_MARKER_PERIOD,
) -> Words:
    """The sensor's training pattern as a (rows, cols) frame.

    Every lane sends ``training_word`` continuously, except that every ``marker_period``-th lane
    word (lane word 0, P, 2P, ...) is ``marker_word`` on all lanes at once: a frame-sync marker
    that leaves every lane at the same instant, so its arrival shows each lane's latency.
    """
    check_training_word(training_word, word_bits)
    marker = default_marker_word(training_word, word_bits) if marker_word is None else marker_word
    _check_marker(marker, training_word, word_bits)
    if marker_period < 2:
        raise ValueError(f"marker period must be at least 2 lane words, got {marker_period}")
    _frame_shape(np.empty((rows, cols), dtype=np.uint8), lanes)
    n = rows * cols // lanes
    stream = np.full(n, training_word, dtype=np.uint16)
    stream[::marker_period] = marker
    return lanes_to_frame(np.broadcast_to(stream, (lanes, n)), rows, cols)


def _check_marker(marker: int, training_word: int, word_bits: int) -> None:
    if not 0 <= marker <= _mask(word_bits):
        raise ValueError(f"marker word 0x{marker:X} does not fit in {word_bits} bits")
    if marker == training_word or marker in rotations(training_word, word_bits):
        raise ValueError(
            f"marker word 0x{marker:X} is the training word 0x{training_word:X} or one of its "
            f"rotations; channel alignment could not tell them apart"
        )


def ramp_frame(rows: int, cols: int, word_bits: int = HR400_WORD_BITS) -> Words:
    """Diagonal ramp ``(row + col) mod 2**word_bits``: a lane or row slip shows as a broken ramp."""
    ramp = np.add.outer(np.arange(rows), np.arange(cols)) & _mask(word_bits)
    return ramp.astype(np.uint16)


_PRBS_ORDER = 15  # PRBS-15, x^15 + x^14 + 1 (ITU-T O.150), period 2^15 - 1 bits


@lru_cache(maxsize=1)
def _prbs15_period() -> npt.NDArray[np.uint8]:
    period = (1 << _PRBS_ORDER) - 1
    bits = np.empty(period + _PRBS_ORDER, dtype=np.uint8)
    bits[:_PRBS_ORDER] = 1  # all-ones start state
    # b[n] = b[n-15] ^ b[n-14]: each chunk of 14 new bits depends only on already known bits.
    n = _PRBS_ORDER
    while n < bits.size:
        k = min(_PRBS_ORDER - 1, bits.size - n)
        bits[n : n + k] = bits[n - 15 : n - 15 + k] ^ bits[n - 14 : n - 14 + k]
        n += k
    return bits[:period]


def prbs_frame(rows: int, cols: int, word_bits: int = HR400_WORD_BITS, seed: int = 0) -> Words:
    """PRBS-15 bit sequence packed MSB first into words, in row-major order.

    ``seed`` selects the phase of the sequence (the generator's start state), so different seeds
    give different frames of the same statistics.
    """
    seq = _prbs15_period()
    nbits = rows * cols * word_bits
    start = seed % seq.size
    idx = (start + np.arange(nbits)) % seq.size
    bits = seq[idx].reshape(rows * cols, word_bits).astype(np.uint16)
    weights = (1 << np.arange(word_bits - 1, -1, -1)).astype(np.uint16)
    return (bits @ weights).astype(np.uint16).reshape(rows, cols)


def pattern_frame(
    pattern: TestPattern,
    rows: int,
    cols: int,
    *,
    word_bits: int = HR400_WORD_BITS,
    lanes: int = HR400_LANES,
    training_word: int = DEFAULT_TRAINING_WORD,
    seed: int = 0,
) -> Words | None:
    """The frame the sensor sends for a TEST_PATTERN value; None for OFF (real pixels)."""
    if pattern is TestPattern.OFF:
        return None
    if pattern is TestPattern.TRAINING:
        return training_frame(rows, cols, training_word, lanes=lanes, word_bits=word_bits)
    if pattern is TestPattern.RAMP:
        return ramp_frame(rows, cols, word_bits)
    return prbs_frame(rows, cols, word_bits, seed)


# -- the link -------------------------------------------------------------------------------------


class LvdsLink:
    """The sensor's serialisers, the board, and the FPGA's input delay and deserialisers."""

    def __init__(
        self,
        *,
        lanes: int = HR400_LANES,
        word_bits: int = HR400_WORD_BITS,
        taps_per_ui: int = DEFAULT_TAPS_PER_UI,
        jitter_taps: int = DEFAULT_JITTER_TAPS,
        seed: int | None = 0,
        max_word_latency: int = DEFAULT_MAX_WORD_LATENCY,
        dead_lanes: Collection[int] = (),
        skews: Sequence[LaneSkew] | None = None,
        idle_word: int = DEFAULT_TRAINING_WORD,
    ) -> None:
        if lanes < 1 or not 2 <= word_bits <= 16:
            raise ValueError(f"need lanes >= 1 and 2 <= word_bits <= 16, got {lanes}, {word_bits}")
        if taps_per_ui < 2 or not 0 <= 2 * jitter_taps < taps_per_ui:
            raise ValueError(
                f"jitter of {jitter_taps} taps closes the eye of a {taps_per_ui}-tap bit period "
                f"(need 0 <= 2 * jitter_taps < taps_per_ui)"
            )
        bad = sorted(set(dead_lanes) - set(range(lanes)))
        if bad:
            raise ValueError(f"dead lanes {bad} out of range 0..{lanes - 1}")
        self.lanes = lanes
        self.word_bits = word_bits
        self.taps_per_ui = taps_per_ui
        self.jitter_taps = jitter_taps
        self.max_word_latency = max_word_latency
        self.dead_lanes = frozenset(dead_lanes)
        self.idle_word = idle_word & _mask(word_bits)
        self.skews: list[LaneSkew] = []
        self._rng = np.random.default_rng()
        self.reskew(seed)
        if skews is not None:
            self.set_skews(skews)

    def reskew(self, seed: int | None) -> None:
        """Draw new random lane skews, as after a power cycle; reseeds the metastability noise."""
        rng = np.random.default_rng(None if seed is None else [_SKEW_STREAM, seed])
        self.skews = [
            LaneSkew(
                delay_taps=int(rng.integers(self.taps_per_ui)),
                bit_offset=int(rng.integers(self.word_bits)),
                word_latency=int(rng.integers(self.max_word_latency + 1)),
            )
            for _ in range(self.lanes)
        ]
        self._rng = np.random.default_rng(None if seed is None else [_NOISE_STREAM, seed])

    def set_skews(self, skews: Sequence[LaneSkew]) -> None:
        """Replace the lane skews with explicit ones (a scripted board for tests)."""
        if len(skews) != self.lanes:
            raise ValueError(f"need {self.lanes} lane skews, got {len(skews)}")
        for skew in skews:
            if min(skew.delay_taps, skew.bit_offset, skew.word_latency) < 0:
                raise ValueError(f"lane skew must not be negative: {skew}")
        self.skews = list(skews)

    @property
    def eye_width_taps(self) -> int:
        """Width of the stable data eye in taps (the same on every live lane)."""
        return self.taps_per_ui - 2 * self.jitter_taps + 1

    def receive(
        self,
        frame: npt.NDArray[Any],
        alignment: Alignment,
        *,
        idle_word: int | None = None,
        rng: np.random.Generator | None = None,
    ) -> Words:
        """The (rows, cols) frame the FPGA captures when the sensor sends ``frame``.

        Bit-exact with trained settings, scrambled otherwise. ``idle_word`` is what the lanes
        carry before and after the frame (default: the link's idle word). Metastable bits come
        from ``rng`` if given, else from the link's own seeded generator.
        """
        rows, cols = _frame_shape(frame, self.lanes)
        streams = frame_to_lanes(frame, self.lanes)
        captured = self.receive_lanes(streams, alignment, idle_word=idle_word, rng=rng)
        return lanes_to_frame(captured, rows, cols)

    def receive_block(self, frames: npt.NDArray[Any], alignment: Alignment) -> Words:
        """``receive`` of each of ``frames`` (``(count, rows, cols)``), the lanes of all of them
        at once (a stream's block: the lane model per frame was a third of a small frame's
        time). The same words as one ``receive`` per frame where the link draws no noise; with
        metastable or dead lanes the noise is drawn lane by lane for the whole block, so it
        differs from frame-by-frame draws (the same distribution)."""
        if frames.ndim != 3:
            raise ValueError(f"need (count, rows, cols) frames, got shape {frames.shape}")
        count = frames.shape[0]
        rows, cols = _frame_shape(frames[0], self.lanes)
        per_row = cols // self.lanes
        streams = np.asarray(frames, dtype=np.uint16).reshape(count, rows, per_row, self.lanes)
        sent = np.ascontiguousarray(streams.transpose(0, 3, 1, 2)).reshape(
            count, self.lanes, rows * per_row
        )
        captured = self._receive_streams(sent, alignment, None, None)
        back = captured.reshape(count, self.lanes, rows, per_row).transpose(0, 2, 3, 1)
        return np.ascontiguousarray(back).reshape(count, rows, cols)

    def bit_exact(self, alignment: Alignment) -> bool:
        """Whether ``alignment`` receives every lane exactly as sent: each live lane's first
        output word starts at the first sent bit, sampled inside the eye (no metastable
        neighbour), and no lane is dead. ``receive`` then returns the frame's own words
        (checked to fit the word size) and draws no noise, so a caller may skip it (the
        frame's lane split and rejoin, two passes over it, a third of a small frame's time)."""
        self._check_alignment(alignment)
        if self.dead_lanes:
            return False
        return all(self._lane_offsets(lane, alignment) == (0, 0) for lane in range(self.lanes))

    def receive_lanes(
        self,
        streams: npt.NDArray[Any],
        alignment: Alignment,
        *,
        idle_word: int | None = None,
        rng: np.random.Generator | None = None,
    ) -> Words:
        """Per-lane capture: (lanes, n) words sent -> (lanes, n) words the deserialisers output."""
        if streams.ndim != 2 or streams.shape[0] != self.lanes:
            raise ValueError(f"need ({self.lanes}, n) lane streams, got shape {streams.shape}")
        sent = np.asarray(streams)[np.newaxis]
        lanes: Words = self._receive_streams(sent, alignment, idle_word, rng)[0]
        return lanes

    def _receive_streams(
        self,
        sent: npt.NDArray[Any],
        alignment: Alignment,
        idle_word: int | None,
        rng: np.random.Generator | None,
    ) -> Words:
        """``receive_lanes`` of several frames' lane streams, ``(frames, lanes, n)``."""
        self._check_alignment(alignment)
        mask = _mask(self.word_bits)
        if sent.size and int(sent.max()) > mask:
            raise ValueError(f"sensor words exceed {self.word_bits} bits (max 0x{mask:X})")
        gen = self._rng if rng is None else rng
        idle = self.idle_word if idle_word is None else idle_word & mask
        count, _, n = sent.shape
        out = np.empty((count, self.lanes, n), dtype=np.uint16)
        for lane in range(self.lanes):
            if lane in self.dead_lanes:
                # An open input: the receiver resolves noise, a different word every time.
                out[:, lane] = gen.integers(0, mask + 1, size=(count, n), dtype=np.uint16)
                continue
            offset, neighbour = self._lane_offsets(lane, alignment)
            words = _bit_window(sent[:, lane], offset, n, self.word_bits, idle)
            if neighbour:
                other = _bit_window(sent[:, lane], offset + neighbour, n, self.word_bits, idle)
                # Where the two candidate bits differ the flip-flop resolves either way.
                noise = gen.integers(0, mask + 1, size=(count, n), dtype=np.uint32)
                words ^= (words ^ other) & noise
            out[:, lane] = words
        return out

    def _check_alignment(self, alignment: Alignment) -> None:
        for name in ("taps", "slips", "shifts"):
            count = len(getattr(alignment, name))
            if count != self.lanes:
                raise ValueError(f"alignment has {count} {name}, link has {self.lanes} lanes")
        if any(not 0 <= t < self.taps_per_ui for t in alignment.taps):
            raise ValueError(f"taps must be in 0..{self.taps_per_ui - 1}: {alignment.taps}")
        if any(not 0 <= s < self.word_bits for s in alignment.slips):
            raise ValueError(f"slips must be in 0..{self.word_bits - 1}: {alignment.slips}")
        if any(s < 0 for s in alignment.shifts) or alignment.latency < 0:
            raise ValueError("lane shifts and latency must not be negative")

    def _lane_offsets(self, lane: int, alignment: Alignment) -> tuple[int, int]:
        """(bit offset of output word 0 in the sent stream, metastable neighbour: -1, 0 or +1)."""
        skew = self.skews[lane]
        period = self.taps_per_ui
        delay = skew.delay_taps + alignment.taps[lane]
        late_bits = (
            skew.word_latency * self.word_bits + skew.bit_offset + -(-delay // period)  # ceil
        )
        first_bit = (alignment.latency - alignment.shifts[lane]) * self.word_bits + alignment.slips[
            lane
        ]
        into_bit = -delay % period  # taps from the start of the sampled bit to the sample
        if into_bit < self.jitter_taps:
            neighbour = -1
        elif period - into_bit < self.jitter_taps:
            neighbour = 1
        else:
            neighbour = 0
        return first_bit - late_bits, neighbour


def _bit_window(
    sent: npt.NDArray[Any], offset: int, count: int, word_bits: int, idle: int
) -> npt.NDArray[np.uint32]:
    """``count`` words read from the bit stream of ``sent`` starting ``offset`` bits in (along
    the last axis: one lane, or the same lane of several frames).

    Outside ``sent`` the stream is ``idle`` words. Each output word is the tail of one sent word
    and the head of the next: two shifts and an or, vectorised over the whole lane.
    """
    first, shift = divmod(offset, word_bits)  # floor division: offset may be negative
    n = sent.shape[-1]
    need = count + 1
    window = np.full((*sent.shape[:-1], need), idle, dtype=np.uint32)
    lo, hi = max(first, 0), min(first + need, n)
    if lo < hi:
        window[..., lo - first : hi - first] = sent[..., lo:hi]
    mask = np.uint32(_mask(word_bits))
    head: npt.NDArray[np.uint32] = (window[..., :-1] << np.uint32(shift)) & mask
    if shift == 0:
        return head
    tail: npt.NDArray[np.uint32] = window[..., 1:] >> np.uint32(word_bits - shift)
    return head | tail
