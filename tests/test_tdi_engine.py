"""The digital TDI engine ``camd.tdi`` against its specification, docs/tdi.md (docs/physics.md §1).

The file carries its own direct implementation of docs/tdi.md (``ReferenceTdi``): it keeps the
frames of the current run and, for every line, sums the stages straight from eq 11 (with row step,
column shift, reverse and the fixed-point interpolation written out as the document states it).
It shares no code with the engine. The engine's two kernels ("numba", "numpy"), every split of the
frames into ``push`` / ``push_many`` calls, and ``tdi_batch`` must all give the reference's bits.

Besides the property tests there are hand-computed cases (literal numbers from eq 11 and eq 12),
the refusal messages, two imaging checks (velocity mismatch and drift: the fractional path gives a
sharper edge than the integer one) and the O(M x N) memory promise.
"""

from __future__ import annotations

import functools
import importlib.util
import math
import re
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from fractions import Fraction
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from camd.tdi import FIXED_POINT_ONE, TdiEngine, tdi_batch

W = 256  # docs/tdi.md: W = 256 steps per pixel (FIXED_POINT_ONE), written out here on purpose
HALF_W = W // 2
KERNELS = ["numpy", "numba"] if importlib.util.find_spec("numba") is not None else ["numpy"]
IMPLS = ["reference", *KERNELS]

Frames = npt.NDArray[np.uint16]
IntArray = npt.NDArray[np.int64]


# == the direct implementation of docs/tdi.md =====================================================


@dataclass(frozen=True)
class Tap:
    """Where stage i samples its frame: row ``r0 + wy / W``, column ``j + d + wx / W``."""

    r0: int
    wy: int
    d: int
    wx: int


def round_half_up(value: float) -> int:
    """round_half_up of docs/tdi.md, computed exactly (no float rounding of ``value + 0.5``)."""
    return math.floor(Fraction(value) + Fraction(1, 2))


def split_position(position: float) -> tuple[int, int]:
    """``p0 = floor(p); w = round_half_up((p - p0) * W); if w == W: p0 += 1, w = 0``."""
    p0 = math.floor(position)
    weight = round_half_up((position - p0) * W)
    if weight == W:
        p0, weight = p0 + 1, 0
    return p0, weight


def stage_taps(stages: int, rows_per_line: float, cols_per_line: float, reverse: bool) -> list[Tap]:
    """The taps of stages 0..M-1: ``y_i = i * rows_per_line`` (reverse: ``(M - 1 - i) * ...``),
    ``x_i = i * cols_per_line``, split into whole pixel and 1/W weight."""
    taps = []
    for i in range(stages):
        y = (stages - 1 - i) * rows_per_line if reverse else i * rows_per_line
        x = i * cols_per_line
        r0, wy = split_position(y)
        d, wx = split_position(x)
        taps.append(Tap(r0, wy, d, wx))
    return taps


def rows_needed(
    stages: int, rows_per_line: float = 1.0, cols_per_line: float = 0.0, reverse: bool = False
) -> int:
    """``max_i(r0 + (1 if wy > 0)) + 1`` (docs/tdi.md "Rows needed")."""
    taps = stage_taps(stages, rows_per_line, cols_per_line, reverse)
    return max(t.r0 + (1 if t.wy > 0 else 0) for t in taps) + 1


@dataclass
class Line:
    """One output line (the reference's TdiLine)."""

    data: npt.NDArray[Any]
    index: int
    stages_used: int
    complete: bool


@dataclass
class Block:
    """Output lines stacked (the reference's TdiBlock, and what the tests compare)."""

    data: npt.NDArray[Any]
    index: npt.NDArray[np.int64]
    stages_used: npt.NDArray[np.int32]
    complete: npt.NDArray[np.bool_]


def stage_values(frames: IntArray, tap: Tap, fractional: bool) -> IntArray:
    """What one stage adds to each column of each of the frames (F, rows, N) -> (F, N):
    DN on the integer path, 1/W DN on the fractional path; 0 where a tap leaves 0..N-1."""
    n = frames.shape[2]
    c0 = np.arange(n) + tap.d
    inside = (c0 >= 0) & (c0 <= n - 1)
    if tap.wx > 0:
        inside &= c0 + 1 <= n - 1
    a = np.clip(c0, 0, n - 1)
    b = np.clip(c0 + 1, 0, n - 1)
    if not fractional:
        value = frames[:, tap.r0, a]
    else:
        zero = np.zeros((frames.shape[0], n), np.int64)
        p00 = frames[:, tap.r0, a]
        p01 = frames[:, tap.r0, b] if tap.wx > 0 else zero
        p10 = frames[:, tap.r0 + 1, a] if tap.wy > 0 else zero
        p11 = frames[:, tap.r0 + 1, b] if tap.wy > 0 and tap.wx > 0 else zero
        wy, wx = tap.wy, tap.wx
        t = (W - wy) * ((W - wx) * p00 + wx * p01) + wy * ((W - wx) * p10 + wx * p11)
        value = (t + HALF_W) // W
    out: IntArray = np.where(inside, value, 0)
    return out


def finish(
    total: IntArray,
    used: npt.NDArray[np.integer[Any]],
    mode: str,
    out_bits: int | None,
    fractional: bool,
) -> npt.NDArray[Any]:
    """Line sums (F, N) -> output: ``mode="sum"`` rounds 1/W DN to DN as (sum + W/2) // W and
    clips to 2^out_bits - 1 (eq 12), as uint32; ``mode="mean"`` divides by stages_used (times
    W on the fractional path) in float64 and rounds once to float32."""
    if mode == "sum":
        dn = (total + HALF_W) // W if fractional else total
        if out_bits is not None:
            dn = np.minimum(dn, 2**out_bits - 1)
        return dn.astype(np.uint32)
    divisor = (W if fractional else 1) * used.astype(np.float64)[:, np.newaxis]
    return (total.astype(np.float64) / divisor).astype(np.float32)


def reference_lines(
    frames: Frames,
    index: Sequence[int] | npt.NDArray[np.int64],
    stages: int,
    mode: str = "sum",
    out_bits: int | None = None,
    rows_per_line: float = 1.0,
    cols_per_line: float = 0.0,
    reverse: bool = False,
) -> Block:
    """One run (from index 0) as a direct strided-diagonal sum, stage by stage: frame ``p``
    has line index ``index[p]`` (indices missing from ``index`` are lost frames); line
    ``index[p]`` adds stage i from the frame with index ``index[p] - i`` if there is one.
    The vectorised twin of ReferenceTdi, for the big cases."""
    idx = np.asarray(index, np.int64)
    taps = stage_taps(stages, rows_per_line, cols_per_line, reverse)
    fractional = not (float(rows_per_line).is_integer() and float(cols_per_line).is_integer())
    position = np.full(int(idx.max()) + 1, -1, np.int64)
    position[idx] = np.arange(len(idx))
    wide = frames.astype(np.int64)
    total = np.zeros((len(idx), frames.shape[2]), np.int64)
    used = np.zeros(len(idx), np.int64)
    for i, tap in enumerate(taps):
        want = idx - i
        source = np.where(want >= 0, position[np.maximum(want, 0)], -1)
        has = source >= 0
        if has.any():
            total[has] += stage_values(wide[source[has]], tap, fractional)
            used += has
    data = finish(total, used, mode, out_bits, fractional)
    return Block(data, idx, used.astype(np.int32), used == stages)


class ReferenceTdi:
    """docs/tdi.md written out directly: no ring, no running sums.

    It remembers the frames of the current run by index and computes each line, when its frame
    arrives, as the sum over the stages i = 0..M-1 whose frame k - i was pushed in this run.
    Integer path: the stage adds ``f[y_i, j + x_i]``; fractional path: the fixed-point bilinear
    tap in 1/W DN. A stage whose taps leave the columns 0..N-1 adds nothing to that column.
    """

    def __init__(
        self,
        stages: int,
        width: int,
        mode: str = "sum",
        out_bits: int | None = None,
        rows_per_line: float = 1.0,
        cols_per_line: float = 0.0,
        reverse: bool = False,
    ) -> None:
        if mode not in ("sum", "mean"):
            raise ValueError(f"unknown mode {mode!r}")
        if out_bits is not None and not 1 <= out_bits <= 32:
            raise ValueError(f"out_bits must be 1..32, got {out_bits}")
        self.width = width
        self.mode = mode
        self.out_bits = out_bits
        self.rows_per_line = rows_per_line
        self.cols_per_line = cols_per_line
        self.reverse = reverse
        self.fractional = not (
            float(rows_per_line).is_integer() and float(cols_per_line).is_integer()
        )
        self.next_index = 0
        self.run_start = 0
        self.frames: dict[int, IntArray] = {}
        self._stages = 0
        self.stages = stages

    @property
    def stages(self) -> int:
        """M; setting it starts a new run."""
        return self._stages

    @stages.setter
    def stages(self, value: int) -> None:
        if value < 1:
            raise ValueError(f"stages must be >= 1, got {value}")
        self._stages = value
        self.taps = stage_taps(value, self.rows_per_line, self.cols_per_line, self.reverse)
        self.rows_needed = max(t.r0 + (1 if t.wy > 0 else 0) for t in self.taps) + 1
        self.run_start = self.next_index  # a new run: older frames never count again
        self.frames.clear()

    def reset(self) -> None:
        """Forget everything; the next frame gets index 0 (a new run)."""
        self.next_index = 0
        self.run_start = 0
        self.frames.clear()

    def gap(self, n_frames: int) -> None:
        """n frames were lost: their indices are skipped (and never found in ``frames``)."""
        self.next_index += n_frames

    def push(self, frame: npt.NDArray[Any]) -> Line:
        """Line k = sum over the stages whose frame k - i is in this run (eq 11)."""
        if frame.shape[-1] != self.width:
            raise ValueError(f"frame width {frame.shape[-1]} != engine width {self.width}")
        if frame.shape[0] < self.rows_needed:
            raise ValueError(f"frame has {frame.shape[0]} rows, needs {self.rows_needed}")
        k = self.next_index
        self.next_index += 1
        self.frames[k] = frame.astype(np.int64)
        total = np.zeros(self.width, np.int64)
        used = 0
        for i, tap in enumerate(self.taps):
            source = self.frames.get(k - i)
            if source is None or k - i < self.run_start:
                continue
            used += 1
            total += stage_values(source[np.newaxis], tap, self.fractional)[0]
        for old in [idx for idx in self.frames if idx <= k - self.stages]:
            del self.frames[old]
        data = finish(
            total[np.newaxis], np.array([used]), self.mode, self.out_bits, self.fractional
        )
        return Line(data[0], k, used, used == self.stages)

    def push_many(self, frames: npt.NDArray[Any]) -> Block:
        """One push per frame."""
        return stack_lines([self.push(f) for f in frames])


def stack_lines(lines: Sequence[Any]) -> Block:
    """TdiLine-like objects -> one Block (data keep their dtype)."""
    return Block(
        data=np.stack([line.data for line in lines]),
        index=np.array([line.index for line in lines], np.int64),
        stages_used=np.array([line.stages_used for line in lines], np.int32),
        complete=np.array([line.complete for line in lines], np.bool_),
    )


def concat_blocks(blocks: Sequence[Block]) -> Block:
    """Blocks one after the other."""
    return Block(
        data=np.concatenate([b.data for b in blocks]),
        index=np.concatenate([b.index for b in blocks]),
        stages_used=np.concatenate([b.stages_used for b in blocks]),
        complete=np.concatenate([b.complete for b in blocks]),
    )


def as_block(block: Any) -> Block:
    """A TdiBlock (checked against docs/tdi.md's shapes and dtypes) -> Block."""
    f = len(block.index)
    assert block.data.ndim == 2 and block.data.shape[0] == f
    assert block.index.dtype == np.int64 and block.index.shape == (f,)
    assert block.stages_used.dtype == np.int32 and block.stages_used.shape == (f,)
    assert block.complete.dtype == np.bool_ and block.complete.shape == (f,)
    return Block(block.data, block.index, block.stages_used, block.complete)


def assert_same(got: Block, want: Block, what: str = "") -> None:
    """Bit-exact equality of data (dtype included), index, stages_used and complete."""
    assert got.data.dtype == want.data.dtype, f"{what}: dtype {got.data.dtype} != {want.data.dtype}"
    assert got.data.shape == want.data.shape, f"{what}: shape {got.data.shape} != {want.data.shape}"
    assert np.array_equal(got.index, want.index), f"{what}: index {got.index} != {want.index}"
    assert np.array_equal(got.stages_used, want.stages_used), (
        f"{what}: stages_used {got.stages_used} != {want.stages_used}"
    )
    assert np.array_equal(got.complete, want.complete), f"{what}: complete differs"
    if not np.array_equal(got.data, want.data):
        bad = np.argwhere(got.data != want.data)
        line, col = (int(v) for v in bad[0])
        raise AssertionError(
            f"{what}: data differ at {len(bad)} places, first line {line} (index "
            f"{want.index[line]}) column {col}: {got.data[line, col]!r} != {want.data[line, col]!r}"
        )


class Engine(Protocol):
    """What the tests drive: TdiEngine or ReferenceTdi."""

    stages: int

    def push(self, frame: npt.NDArray[Any]) -> Any: ...
    def push_many(self, frames: npt.NDArray[Any]) -> Any: ...
    def gap(self, n_frames: int) -> None: ...
    def reset(self) -> None: ...


def make(impl: str, **kwargs: Any) -> Engine:
    """The reference, or TdiEngine with the named kernel."""
    if impl == "reference":
        return ReferenceTdi(**kwargs)
    engine: Engine = TdiEngine(kernel=impl, **kwargs)
    return engine


# == scenarios: frames plus a script of pushes, gaps, stage changes and resets ====================

Event = tuple[str, int]  # ("push", n frames) | ("gap", n) | ("stages", M) | ("reset", 0)


@dataclass
class Scenario:
    """Engine settings, frames, and what happens to the stream between them."""

    stages: int
    width: int
    rows: int
    rows_per_line: float
    cols_per_line: float
    reverse: bool
    mode: str
    out_bits: int | None
    frames: Frames
    events: list[Event]
    split_seed: int

    def settings(self) -> dict[str, Any]:
        return {
            "stages": self.stages,
            "width": self.width,
            "mode": self.mode,
            "out_bits": self.out_bits,
            "rows_per_line": self.rows_per_line,
            "cols_per_line": self.cols_per_line,
            "reverse": self.reverse,
        }


def make_frames(rng: np.random.Generator, shape: tuple[int, ...], values: str) -> Frames:
    """Random uint16 frames: 12-bit, the full 16-bit range, mostly 0/65535 extremes, or small."""
    if values == "12bit":
        return rng.integers(0, 4096, size=shape, dtype=np.uint16)
    if values == "full":
        return rng.integers(0, 65536, size=shape, dtype=np.uint16)
    if values == "extreme":
        pick = rng.integers(0, 4, size=shape)
        return np.where(pick == 0, 0, np.where(pick == 1, 65534, 65535)).astype(np.uint16)
    return rng.integers(0, 16, size=shape, dtype=np.uint16)


ROWS_PER_LINE = st.one_of(
    st.sampled_from([1.0, 2.0, 3.0]),
    st.floats(-0.12, 0.12).map(lambda e: 1.0 + e),  # velocity mismatch 1 + e
    st.floats(0.5, 2.5),
    st.integers(256, 640).map(lambda n: n / 256),  # exact on the 1/W lattice
    st.integers(256, 1280).map(lambda n: n / 512),  # half steps: round_half_up ties
)
COLS_PER_LINE = st.one_of(
    st.just(0.0),
    st.integers(-2, 2).map(float),
    st.floats(-1.5, 1.5),
    st.integers(-1024, 1024).map(lambda n: n / 512),
)
EVENT = st.one_of(
    st.tuples(st.just("push"), st.integers(1, 12)),
    st.tuples(st.just("push"), st.integers(1, 12)),
    st.tuples(st.just("gap"), st.integers(1, 15)),
    st.tuples(st.just("stages"), st.integers(1, 12)),
    st.tuples(st.just("reset"), st.just(0)),
)


@st.composite
def scenarios(draw: st.DrawFn, events: bool = True, max_frames: int = 40) -> Scenario:
    """Random M (1..12), N (1..40), F (1..40), geometry, mode, data and (optionally) events."""
    stages = draw(st.integers(1, 12))
    width = draw(st.integers(1, 40))
    rows_per_line = draw(ROWS_PER_LINE)
    cols_per_line = draw(COLS_PER_LINE)
    reverse = draw(st.booleans())
    mode = draw(st.sampled_from(["sum", "sum", "mean"]))
    out_bits = draw(st.one_of(st.none(), st.integers(1, 32))) if mode == "sum" else None
    if events:
        script = draw(st.lists(EVENT, min_size=1, max_size=10))
        script.append(("push", draw(st.integers(1, 12))))
    else:
        script = [("push", draw(st.integers(1, max_frames)))]
    kept: list[Event] = []
    total = 0
    for kind, n in script:  # at most max_frames frames in all
        if kind == "push":
            n = min(n, max_frames - total)
            if n == 0:
                continue
            total += n
        kept.append((kind, n))
    all_stages = [stages] + [n for kind, n in kept if kind == "stages"]
    needed = max(rows_needed(m, rows_per_line, cols_per_line, reverse) for m in all_stages)
    rows = needed + draw(st.sampled_from([0, 0, 1, 3]))
    values = draw(st.sampled_from(["12bit", "full", "extreme", "small"]))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    frames = make_frames(rng, (total, rows, width), values)
    return Scenario(
        stages,
        width,
        rows,
        rows_per_line,
        cols_per_line,
        reverse,
        mode,
        out_bits,
        frames,
        kept,
        draw(st.integers(0, 2**32 - 1)),
    )


def chunks(frames: Frames, how: str, rng: np.random.Generator) -> Iterator[tuple[str, Frames]]:
    """Split frames into calls: all single ``push``, one ``push_many``, or random pieces."""
    if how == "push":
        for frame in frames:
            yield "push", frame
    elif how == "many":
        yield "many", frames
    else:
        start = 0
        while start < len(frames):
            size = int(rng.integers(1, len(frames) - start + 1))
            piece = frames[start : start + size]
            if size == 1 and rng.integers(2):
                yield "push", piece[0]
            else:
                yield "many", piece
            start += size


def run(engine: Engine, scenario: Scenario, how: str) -> Block:
    """Play the scenario's script on an engine, splitting the pushes as ``how`` says."""
    rng = np.random.default_rng(scenario.split_seed)
    blocks: list[Block] = []
    current = scenario.stages
    start = 0
    for kind, n in scenario.events:
        if kind == "push":
            for call, data in chunks(scenario.frames[start : start + n], how, rng):
                if call == "push":
                    line = engine.push(data)
                    assert line.data.shape == (scenario.width,)
                    blocks.append(stack_lines([line]))
                else:
                    blocks.append(as_block(engine.push_many(data)))
            start += n
        elif kind == "gap":
            engine.gap(n)
        elif kind == "stages":
            if n != current:  # only real changes (docs: "every change of stages")
                engine.stages = n
                current = n
        else:
            engine.reset()
    return concat_blocks(blocks)


# == 1-2. property tests: kernels, splits and tdi_batch against the direct implementation ========


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scenario=scenarios())
def test_kernels_and_splits_match_the_direct_implementation(scenario: Scenario) -> None:
    """Any geometry (row step, fractional rows, column shift, reverse), mode, out_bits, data
    range, and any script of pushes, gaps, stage changes and resets: both kernels, fed frame by
    frame, in one push_many per script step, or in random push/push_many pieces, give exactly
    the direct implementation's data (bits and dtype), indices, stages_used and complete."""
    want = run(ReferenceTdi(**scenario.settings()), scenario, "many")
    expected_dtype = np.uint32 if scenario.mode == "sum" else np.float32
    assert want.data.dtype == expected_dtype
    if all(kind in ("push", "gap") for kind, _ in scenario.events):  # one run: the twins agree
        settings_ = {k: v for k, v in scenario.settings().items() if k != "width"}
        assert_same(reference_lines(scenario.frames, want.index, **settings_), want, "twin")
    for kernel in KERNELS:
        for how in ("push", "many", "random"):
            got = run(make(kernel, **scenario.settings()), scenario, how)
            assert_same(got, want, f"kernel={kernel} split={how}")


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scenario=scenarios(events=False))
def test_tdi_batch_matches_the_engine_and_the_direct_implementation(scenario: Scenario) -> None:
    """tdi_batch(frames, ...) on one gap-free run gives the same data and complete flags as the
    engine and as the direct implementation."""
    settings_ = scenario.settings()
    want = ReferenceTdi(**settings_).push_many(scenario.frames)
    batch_settings = {k: v for k, v in settings_.items() if k != "width"}
    for kernel in KERNELS:
        data, complete = tdi_batch(scenario.frames, kernel=kernel, **batch_settings)
        assert data.dtype == want.data.dtype
        assert np.array_equal(data, want.data), f"tdi_batch kernel={kernel}"
        assert complete.dtype == np.bool_
        assert np.array_equal(complete, want.complete)
        got = as_block(make(kernel, **settings_).push_many(scenario.frames))
        assert_same(got, want, f"kernel={kernel}")


@settings(max_examples=60, deadline=None)
@given(
    stages=st.integers(1, 12),
    rows_per_line=ROWS_PER_LINE,
    cols_per_line=COLS_PER_LINE,
    reverse=st.booleans(),
)
def test_rows_needed_is_exactly_the_documented_number(
    stages: int, rows_per_line: float, cols_per_line: float, reverse: bool
) -> None:
    """A frame of rows_needed rows is taken; one row fewer is refused, naming both numbers."""
    need = rows_needed(stages, rows_per_line, cols_per_line, reverse)
    eng = TdiEngine(
        stages=stages,
        width=3,
        rows_per_line=rows_per_line,
        cols_per_line=cols_per_line,
        reverse=reverse,
    )
    eng.push(np.zeros((need, 3), np.uint16))
    if need > 1:
        with pytest.raises(ValueError, match=names_numbers(need - 1, need)):
            eng.push(np.zeros((need - 1, 3), np.uint16))


def test_rows_needed_examples_from_the_docs() -> None:
    """docs/tdi.md: M in the synchronous case, 2M - 1 with rows_per_line = 2; and a fractional
    example worked by hand: M = 4, 1.5 rows per line -> y_3 = 4.5 -> r0 = 4, wy = 128 -> 6."""
    assert rows_needed(7) == 7
    assert rows_needed(7, 2.0) == 13
    assert rows_needed(4, 1.5) == 6
    assert rows_needed(4, 1.5, reverse=True) == 6
    assert rows_needed(3, 0.999) == 3  # y_2 = 1.998: 0.998 * 256 rounds to 256 -> r0 = 2, wy = 0


# == 3. hand-computed cases =======================================================================

# Five 3 x 2 frames (rows x columns), values chosen so every row and frame is recognisable.
HAND = np.array(
    [
        [[1, 2], [3, 4], [5, 6]],
        [[10, 20], [30, 40], [50, 60]],
        [[100, 200], [300, 400], [500, 600]],
        [[1000, 2000], [3000, 4000], [5000, 6000]],
        [[7, 9], [9, 11], [13, 17]],
    ],
    np.uint16,
)


def push_all(eng: Engine, frames: npt.NDArray[Any]) -> Block:
    """Each frame through ``push`` (one TdiLine each), stacked."""
    return stack_lines([eng.push(f) for f in frames])


@pytest.mark.parametrize("impl", IMPLS)
def test_eq11_by_hand_m3(impl: str) -> None:
    """M = 3: S(k) = f_k[0] + f_{k-1}[1] + f_{k-2}[2] (eq 11); lines 0 and 1 have 1 and 2 stages
    and are flagged incomplete; push_many gives the same block."""
    got = push_all(make(impl, stages=3, width=2), HAND)
    assert got.data.tolist() == [[1, 2], [13, 24], [135, 246], [1350, 2460], [3507, 4609]]
    assert got.data.dtype == np.uint32
    assert got.index.tolist() == [0, 1, 2, 3, 4]
    assert got.stages_used.tolist() == [1, 2, 3, 3, 3]
    assert got.complete.tolist() == [False, False, True, True, True]
    assert_same(as_block(make(impl, stages=3, width=2).push_many(HAND)), got, "push_many")


@pytest.mark.parametrize("impl", IMPLS)
def test_reverse_by_hand_m3(impl: str) -> None:
    """reverse=True: S(k) = f_k[2] + f_{k-1}[1] + f_{k-2}[0] (the scene moves from row 1 to M)."""
    got = push_all(make(impl, stages=3, width=2, reverse=True), HAND)
    assert got.data.tolist() == [[5, 6], [53, 64], [531, 642], [5310, 6420], [3113, 4217]]
    assert got.stages_used.tolist() == [1, 2, 3, 3, 3]


@pytest.mark.parametrize("impl", IMPLS)
def test_row_step_two_by_hand(impl: str) -> None:
    """rows_per_line = 2 ("every other row"): M = 2 needs 3 rows; S(k) = f_k[0] + f_{k-1}[2]."""
    got = push_all(make(impl, stages=2, width=2, rows_per_line=2), HAND)
    assert got.data.tolist() == [[1, 2], [15, 26], [150, 260], [1500, 2600], [5007, 6009]]


@pytest.mark.parametrize("impl", IMPLS)
def test_integer_column_shift_by_hand(impl: str) -> None:
    """cols_per_line = 1: stage i reads column j + i; a column past the edge adds nothing.
    M = 2: S(k)[0] = f_k[0,0] + f_{k-1}[1,1]; S(k)[1] = f_k[0,1] (stage 1 would read column 2)."""
    got = push_all(make(impl, stages=2, width=2, cols_per_line=1), HAND[:3])
    assert got.data.tolist() == [[1, 2], [14, 20], [140, 200]]
    assert got.stages_used.tolist() == [1, 2, 2]
    left = push_all(make(impl, stages=2, width=2, cols_per_line=-1), HAND[:3])
    assert left.data.tolist() == [[1, 2], [10, 23], [100, 230]]


@pytest.mark.parametrize("impl", IMPLS)
def test_gap_of_one_frame_by_hand(impl: str) -> None:
    """M = 3, frames 0, 1, (2 lost), 3, 4, 5, 6. Lines 3 and 4 span the lost frame 2, so they
    have 2 stages (3 + 1, and 4 + 3): exactly the M - 1 lines after the gap are incomplete, and
    line 3 still includes frame 1 (a stage that was there), never a frame in place of frame 2."""
    eng = make(impl, stages=3, width=2)
    first = push_all(eng, HAND[:2])
    eng.gap(1)
    later = [HAND[3], HAND[4], HAND[1], HAND[2]]  # frames 3, 4, 5, 6
    rest = push_all(eng, np.stack(later))
    got = concat_blocks([first, rest])
    assert got.index.tolist() == [0, 1, 3, 4, 5, 6]
    assert got.stages_used.tolist() == [1, 2, 2, 2, 3, 3]
    assert got.complete.tolist() == [False, False, False, False, True, True]
    # line 3: f3[0] + f1[2]; line 4: f4[0] + f3[1]; line 5: f5[0] + f4[1] + f3[2]; line 6: ...
    assert got.data.tolist() == [
        [1, 2],
        [13, 24],
        [1000 + 50, 2000 + 60],
        [7 + 3000, 9 + 4000],
        [10 + 9 + 5000, 20 + 11 + 6000],
        [100 + 30 + 13, 200 + 40 + 17],
    ]


@pytest.mark.parametrize("impl", IMPLS)
def test_long_gap_and_reset_by_hand(impl: str) -> None:
    """A gap of >= M frames leaves nothing to add: the next lines restart at 1 stage. reset()
    forgets everything: indices restart at 0 and the first M - 1 lines are incomplete again."""
    eng = make(impl, stages=2, width=2)
    push_all(eng, HAND[:2])
    eng.gap(5)
    after_gap = push_all(eng, HAND[2:4])
    assert after_gap.index.tolist() == [7, 8]
    assert after_gap.stages_used.tolist() == [1, 2]
    assert after_gap.data.tolist() == [[100, 200], [1300, 2400]]
    eng.reset()
    after_reset = push_all(eng, HAND[3:5])
    assert after_reset.index.tolist() == [0, 1]
    assert after_reset.stages_used.tolist() == [1, 2]
    assert after_reset.complete.tolist() == [False, True]
    assert after_reset.data.tolist() == [[1000, 2000], [3007, 4009]]


@pytest.mark.parametrize("impl", IMPLS)
def test_gap_before_the_first_frame(impl: str) -> None:
    """gap(n) before anything was pushed skips indices 0..n-1; the run still starts empty."""
    eng = make(impl, stages=2, width=2)
    eng.gap(3)
    got = push_all(eng, HAND[:2])
    assert got.index.tolist() == [3, 4]
    assert got.stages_used.tolist() == [1, 2]


@pytest.mark.parametrize("impl", IMPLS)
def test_stage_change_starts_a_new_run_by_hand(impl: str) -> None:
    """M = 3 for frames 0-2, then stages = 2: the indices go on (3, 4), line 3 has 1 stage (the
    older frames belong to the previous run), line 4 = f4[0] + f3[1] is complete at M = 2."""
    eng = make(impl, stages=3, width=2)
    before = push_all(eng, HAND[:3])
    assert before.stages_used.tolist() == [1, 2, 3]
    eng.stages = 2
    assert eng.stages == 2
    after = push_all(eng, HAND[3:5])
    assert after.index.tolist() == [3, 4]
    assert after.stages_used.tolist() == [1, 2]
    assert after.complete.tolist() == [False, True]
    assert after.data.tolist() == [[1000, 2000], [3007, 4009]]
    eng.stages = 3  # growing M also starts over (M - 1 = 2 incomplete lines)
    grown = push_all(eng, HAND)
    assert grown.index.tolist() == [5, 6, 7, 8, 9]
    assert grown.stages_used.tolist() == [1, 2, 3, 3, 3]
    assert grown.complete.tolist() == [False, False, True, True, True]
    assert grown.data.tolist() == [[1, 2], [13, 24], [135, 246], [1350, 2460], [3507, 4609]]


@pytest.mark.parametrize("impl", IMPLS)
def test_out_bits_clip_eq12(impl: str) -> None:
    """eq 12: S' = min(S, 2^n - 1). With n = 8 the M = 3 sums of the hand frames become
    [1, 2], [13, 24], [135, 246], [255, 255], [255, 255]; n = 11 clips at 2047."""
    eight = push_all(make(impl, stages=3, width=2, out_bits=8), HAND)
    assert eight.data.tolist() == [[1, 2], [13, 24], [135, 246], [255, 255], [255, 255]]
    assert eight.data.dtype == np.uint32
    eleven = push_all(make(impl, stages=3, width=2, out_bits=11), HAND)
    assert eleven.data.tolist() == [[1, 2], [13, 24], [135, 246], [1350, 2047], [2047, 2047]]


@pytest.mark.parametrize("impl", IMPLS)
def test_full_scale_sums_do_not_wrap(impl: str) -> None:
    """Three 65535 stages sum to 196605 in uint32 (no 16-bit wrap); out_bits = 16 gives 65535,
    out_bits = 32 clips nothing."""
    full = np.full((4, 3, 2), 65535, np.uint16)
    plain = push_all(make(impl, stages=3, width=2), full)
    assert plain.data[:, 0].tolist() == [65535, 131070, 196605, 196605]
    clipped = push_all(make(impl, stages=3, width=2, out_bits=16), full)
    assert clipped.data[:, 0].tolist() == [65535, 65535, 65535, 65535]
    wide = push_all(make(impl, stages=3, width=2, out_bits=32), full)
    assert wide.data[:, 0].tolist() == [65535, 131070, 196605, 196605]


@pytest.mark.parametrize("impl", IMPLS)
def test_mean_mode_by_hand(impl: str) -> None:
    """mode="mean": float32 of (sum / stages_used) in float64; the partial lines divide by the
    stages they have (line 1: 13 / 2 = 6.5), line 4: 4609 / 3 rounded once to float32."""
    got = push_all(make(impl, stages=3, width=2, mode="mean"), HAND)
    assert got.data.dtype == np.float32
    want = np.array(
        [[1, 2], [13 / 2, 24 / 2], [135 / 3, 246 / 3], [1350 / 3, 2460 / 3], [3507 / 3, 4609 / 3]]
    ).astype(np.float32)
    assert np.array_equal(got.data, want)
    assert got.data[1].tolist() == [6.5, 12.0]
    assert got.data[4, 1] == np.float32(4609 / 3)


@pytest.mark.parametrize("impl", IMPLS)
def test_fractional_rows_by_hand(impl: str) -> None:
    """rows_per_line = 1.5, M = 2: stage 1 reads row 1.5 (r0 = 1, wy = 128) = the average of
    rows 1 and 2, in 1/W DN 128 * (p1 + p2). Line 1 = 256 * 10 + 128 * (3 + 4) = 3456 / 256 =
    13.5 DN: mode sum rounds half up to 14, mode mean gives 3456 / 512 = 6.75."""
    frames = np.array([[[0], [3], [4]], [[10], [0], [0]]], np.uint16)
    got = push_all(make(impl, stages=2, width=1, rows_per_line=1.5), frames)
    assert got.data[:, 0].tolist() == [0, 14]
    mean = push_all(make(impl, stages=2, width=1, rows_per_line=1.5, mode="mean"), frames)
    assert mean.data[:, 0].tolist() == [0.0, 6.75]


@pytest.mark.parametrize("impl", IMPLS)
def test_fractional_columns_by_hand(impl: str) -> None:
    """cols_per_line = 0.25, M = 2: stage 1 reads column j + 0.25 (d = 0, wx = 64), i.e.
    (192 p_j + 64 p_{j+1}) / 256; the last column's tap j + 1 is outside, so it adds nothing.
    Frame 0 row 1 = [4, 8, 100]: column 0 gets 1280/256 = 5, column 1 gets 7936/256 = 31.
    cols_per_line = -0.25: d = -1, wx = 192: column 0 adds nothing, column 1 gets
    (64 * 4 + 192 * 8) / 256 = 7, column 2 (64 * 8 + 192 * 100) / 256 = 77."""
    frames = np.array([[[0, 0, 0], [4, 8, 100]], [[1, 2, 3], [0, 0, 0]]], np.uint16)
    right = push_all(make(impl, stages=2, width=3, cols_per_line=0.25), frames)
    assert right.data.tolist() == [[0, 0, 0], [1 + 5, 2 + 31, 3]]
    left = push_all(make(impl, stages=2, width=3, cols_per_line=-0.25), frames)
    assert left.data.tolist() == [[0, 0, 0], [1, 2 + 7, 3 + 77]]
    assert left.stages_used.tolist() == [1, 2]  # per line, whatever the edge columns got


@pytest.mark.parametrize("impl", IMPLS)
def test_fixed_point_rounds_half_up(impl: str) -> None:
    """round_half_up, not half-to-even or truncation, at each of the three roundings:
    - weight: rows_per_line = 1 + 1/512 -> (y - r0) * W = 0.5 -> wy = 1 (half-even gives 0);
      stage 1 of line 1 = 255 * p1 + 1 * p2 = 256 (p1 = 0, p2 = 256) -> 1 DN;
    - stage value: with cols_per_line = 1/512 as well (wx = 1), p11 = 128 alone gives t = 128,
      v = (128 + 128) // 256 = 1 (1/W DN), seen in mode mean as 1 / 512;
    - line: 3456 / 256 = 13.5 -> 14 (test_fractional_rows_by_hand)."""
    frames = np.array([[[0, 0], [0, 0], [256, 0]], [[0, 0], [0, 0], [0, 0]]], np.uint16)
    got = push_all(make(impl, stages=2, width=2, rows_per_line=1 + 1 / 512), frames)
    assert got.data.tolist() == [[0, 0], [1, 0]]
    tiny = np.array([[[0, 0], [0, 0], [0, 128]], [[0, 0], [0, 0], [0, 0]]], np.uint16)
    eng = make(
        impl, stages=2, width=2, rows_per_line=1 + 1 / 512, cols_per_line=1 / 512, mode="mean"
    )
    mean = push_all(eng, tiny)
    assert mean.data[1, 0] == np.float32(1 / 512)


def test_fixed_point_one_is_256() -> None:
    """The documented fixed-point scale."""
    assert FIXED_POINT_ONE == 256


@pytest.mark.parametrize("kernel", KERNELS)
def test_line_and_block_types(kernel: str) -> None:
    """TdiLine: data (N,), index int, stages_used int, complete bool; TdiBlock arrays as
    documented (int64 index, int32 stages_used, bool complete)."""
    eng = TdiEngine(stages=2, width=2, kernel=kernel)
    line = eng.push(HAND[0])
    assert line.data.shape == (2,) and line.data.dtype == np.uint32
    assert isinstance(line.index, int) and line.index == 0
    assert isinstance(line.stages_used, int) and line.stages_used == 1
    assert isinstance(line.complete, bool) and line.complete is False
    block = as_block(eng.push_many(HAND[1:]))
    assert block.data.shape == (4, 2)
    assert block.index.tolist() == [1, 2, 3, 4]


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_narrow_integer_dtypes_are_taken(dtype: type[np.unsignedinteger[Any]]) -> None:
    """8- and 16-bit unsigned frames are taken and summed without wrapping in their dtype."""
    eng = TdiEngine(stages=3, width=2)
    got = as_block(eng.push_many(np.full((3, 3, 2), 200, dtype)))
    assert got.data[:, 0].tolist() == [200, 400, 600]


# == 4. refusals ==================================================================================


def names_numbers(*numbers: int) -> str:
    """A regex that matches a message naming every one of the numbers (any order)."""
    return "(?s)" + "".join(rf"(?=.*(?<!\d){n}(?!\d))" for n in numbers)


def test_too_few_rows_is_refused_naming_both_numbers() -> None:
    """M = 5 needs 5 rows; rows_per_line = 2 with M = 4 needs 7; the messages name got/needed,
    for push, push_many and tdi_batch."""
    with pytest.raises(ValueError, match=names_numbers(4, 5)):
        TdiEngine(stages=5, width=8).push(np.zeros((4, 8), np.uint16))
    with pytest.raises(ValueError, match=names_numbers(6, 7)):
        TdiEngine(stages=4, width=8, rows_per_line=2).push(np.zeros((6, 8), np.uint16))
    with pytest.raises(ValueError, match=names_numbers(4, 5)):
        TdiEngine(stages=5, width=8).push_many(np.zeros((3, 4, 8), np.uint16))
    with pytest.raises(ValueError, match=names_numbers(4, 5)):
        tdi_batch(np.zeros((3, 4, 8), np.uint16), stages=5)


def test_wrong_width_is_refused() -> None:
    """A frame of 7 columns on an engine of width 8: ValueError naming 7 and 8."""
    with pytest.raises(ValueError, match=names_numbers(7, 8)):
        TdiEngine(stages=3, width=8).push(np.zeros((3, 7), np.uint16))
    with pytest.raises(ValueError, match=names_numbers(7, 8)):
        TdiEngine(stages=3, width=8).push_many(np.zeros((2, 3, 7), np.uint16))


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.uint32, np.int64])
def test_float_or_wide_dtype_is_refused(dtype: type[np.generic]) -> None:
    """Float frames and integers wider than 16 bits are refused with a message on the dtype."""
    with pytest.raises(ValueError, match=re.compile(r"dtype|float|integer|16", re.I)):
        TdiEngine(stages=3, width=4).push(np.zeros((3, 4), dtype))
    with pytest.raises(ValueError, match=re.compile(r"dtype|float|integer|16", re.I)):
        TdiEngine(stages=3, width=4).push_many(np.zeros((2, 3, 4), dtype))


@pytest.mark.parametrize("stages", [0, -1])
def test_stages_below_one_is_refused(stages: int) -> None:
    """stages < 1 at construction, by the setter and in tdi_batch."""
    with pytest.raises(ValueError, match="stages"):
        TdiEngine(stages=stages, width=4)
    eng = TdiEngine(stages=2, width=4)
    with pytest.raises(ValueError, match="stages"):
        eng.stages = stages
    with pytest.raises(ValueError, match="stages"):
        tdi_batch(np.zeros((2, 3, 4), np.uint16), stages=stages)


def test_unknown_mode_is_refused() -> None:
    """mode must be "sum" or "mean"; the message names the bad one."""
    with pytest.raises(ValueError, match="median"):
        TdiEngine(stages=3, width=4, mode="median")


@pytest.mark.parametrize("out_bits", [0, 33, -8])
def test_out_bits_outside_1_to_32_is_refused(out_bits: int) -> None:
    """out_bits must be 1..32 (eq 12's n)."""
    with pytest.raises(ValueError, match="out_bits"):
        TdiEngine(stages=3, width=4, out_bits=out_bits)


# == 5. imaging: velocity mismatch and drift ======================================================


def log_cosh(z: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """ln cosh z without overflow."""
    a = np.abs(z)
    out: npt.NDArray[np.float64] = a + np.log1p(np.exp(-2.0 * a)) - math.log(2.0)
    return out


def pixel_edge(lo: npt.NDArray[np.float64], centre: float, scale: float) -> npt.NDArray[np.float64]:
    """Mean of the edge (1 + tanh((u - centre) / scale)) / 2 over the pixel [lo, lo + 1),
    integrated exactly: the antiderivative of tanh is ln cosh."""
    hi = lo + 1.0
    z_hi = (hi - centre) / scale
    z_lo = (lo - centre) / scale
    out: npt.NDArray[np.float64] = 0.5 + 0.5 * scale * (log_cosh(z_hi) - log_cosh(z_lo))
    return out


def edge_width(profile: npt.NDArray[Any]) -> float:
    """10-90 % width in samples of a rising edge, normalised to its first and last samples,
    with linear interpolation between the samples that bracket each level."""
    p = np.asarray(profile, np.float64)
    q = (p - p[0]) / (p[-1] - p[0])

    def crossing(level: float) -> float:
        i = int(np.argmax(q >= level))
        return float(i - 1 + (level - q[i - 1]) / (q[i] - q[i - 1]))

    return crossing(0.9) - crossing(0.1)


AMPLITUDE = 4000.0  # DN, 12-bit scene
EDGE_SCALE = 0.3  # rows (or columns): a sharp but smooth edge


def along_track_frames(stages: int, speed: float, n_frames: int, rows: int) -> Frames:
    """Frames of a scene with an edge across the rows, moving ``speed`` rows per frame towards
    row 0: row r of frame t sees scene rows [r + speed t, r + 1 + speed t)."""
    centre = speed * (stages + 20)  # output line ~ M + 20 sees the edge
    t = np.arange(n_frames, dtype=np.float64)[:, None]
    r = np.arange(rows, dtype=np.float64)[None, :]
    profile = AMPLITUDE * pixel_edge(r + speed * t, centre, EDGE_SCALE)
    frames = np.round(profile).astype(np.uint16)
    return np.repeat(frames[:, :, None], 4, axis=2)


@pytest.mark.parametrize(
    ("stages", "e", "max_ratio"),
    [(24, 0.1, 0.85), (32, 0.08, 0.85), (32, 0.1, 0.72), (48, 0.1, 0.58), (32, 0.15, 0.58)],
)
def test_fractional_row_step_corrects_velocity_mismatch(
    stages: int, e: float, max_ratio: float
) -> None:
    """The scene moves 1 + e rows per frame. rows_per_line = 1 smears the edge over M e rows
    (10-90 % width about single + 0.55 M e lines); rows_per_line = 1 + e registers every stage
    on the same scene line, so the edge stays within about one line of a single frame's
    (linear interpolation costs about 0.8 line), whatever M e. The gain is a ratio of 0.65 at
    M e = 3.2 and 0.5 at M e = 4.8 (below M e of about 1.6 interpolation blurs more than the
    mismatch does, so those cases are not asserted)."""
    speed = 1.0 + e
    n_frames = stages + 45
    rows = rows_needed(stages, speed) + 2
    frames = along_track_frames(stages, speed, n_frames, rows)

    def width(rows_per_line: float, m: int) -> float:
        data, complete = tdi_batch(frames, stages=m, mode="mean", rows_per_line=rows_per_line)
        assert complete[stages - 1 :].all()
        return edge_width(data[stages - 1 :, 1])

    single = width(1.0, 1)
    integer = width(1.0, stages)
    fractional = width(speed, stages)
    assert integer > single + 0.45 * stages * e  # the mismatch really smears
    assert fractional < max_ratio * integer
    assert fractional < single + 1.1


def drift_frames(stages: int, drift: float, n_frames: int, width: int, centre: float) -> Frames:
    """Frames of a scene with an edge across the columns (uniform along the rows, so the row
    motion does not matter), moving ``drift`` columns per frame towards column 0."""
    t = np.arange(n_frames, dtype=np.float64)[:, None]
    j = np.arange(width, dtype=np.float64)[None, :]
    profile = AMPLITUDE * pixel_edge(j + drift * t, centre + drift * (n_frames - 1), EDGE_SCALE)
    frames = np.round(profile).astype(np.uint16)
    return np.repeat(frames[:, None, :], stages, axis=1)


@pytest.mark.parametrize(
    ("stages", "drift", "max_ratio"),
    [(16, 0.2, 0.72), (16, 0.3, 0.58), (24, 0.25, 0.5), (32, 0.3, 0.35)],
)
def test_fractional_column_shift_corrects_drift(
    stages: int, drift: float, max_ratio: float
) -> None:
    """The scene also drifts c columns per frame (drift angle). cols_per_line = 0 smears the
    edge over M c columns; cols_per_line = c lines the stages up, so the 10-90 % width of the
    last line's column profile stays within about one column of a single frame's (ratio to the
    integer width 0.65 at M c = 3.2, 0.26 at M c = 9.6)."""
    width = 64
    n_frames = stages + 4
    frames = drift_frames(stages, drift, n_frames, width, centre=24.0)
    usable = slice(0, width - math.ceil((stages - 1) * drift) - 2)  # every stage inside

    def edge(cols_per_line: float, m: int) -> float:
        data, complete = tdi_batch(frames, stages=m, mode="mean", cols_per_line=cols_per_line)
        assert complete[-1]
        return edge_width(data[-1, usable])

    single = edge(0.0, 1)
    integer = edge(0.0, stages)
    fractional = edge(drift, stages)
    assert integer > single + 0.45 * stages * drift
    assert fractional < max_ratio * integer
    assert fractional < single + 1.1


# == 6. memory ====================================================================================


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("rows_per_line", [1.0, 1.1])
def test_state_is_o_m_n_whatever_the_scan_length(kernel: str, rows_per_line: float) -> None:
    """state_bytes after 10 frames = after 10000 single pushes = after push_many of 5000 more,
    and it is the ring of M partial sums, M x N x 4 bytes (uint32)."""
    m, n = 16, 64
    rows = rows_needed(m, rows_per_line)
    rng = np.random.default_rng(5)
    frames = rng.integers(0, 4096, size=(64, rows, n), dtype=np.uint16)
    eng = TdiEngine(stages=m, width=n, kernel=kernel, rows_per_line=rows_per_line)
    for i in range(10):
        eng.push(frames[i % 64])
    after_10 = eng.state_bytes
    assert after_10 == m * n * 4
    for i in range(10, 10_000):
        eng.push(frames[i % 64])
    assert eng.state_bytes == after_10
    eng.push_many(np.tile(frames, (79, 1, 1))[:5000])
    assert eng.state_bytes == after_10
    eng.gap(3)
    eng.push(frames[0])
    assert eng.state_bytes == after_10


# == 7. bigger cases ==============================================================================


@functools.cache
def big_case(mode: str, out_bits: int | None) -> tuple[Frames, Block]:
    """M = 96, N = 64, 300 frames of 12-bit data, with the direct implementation's output."""
    rng = np.random.default_rng(96)
    frames = rng.integers(0, 4096, size=(300, 96, 64), dtype=np.uint16)
    ref = ReferenceTdi(stages=96, width=64, mode=mode, out_bits=out_bits)
    return frames, ref.push_many(frames)


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize(("mode", "out_bits"), [("sum", None), ("sum", 16), ("mean", None)])
def test_integer_path_m96_12bit_matches_direct(
    kernel: str, mode: str, out_bits: int | None
) -> None:
    """The integer path at 12-bit data, M = 96, N = 64, 300 frames (sums up to 393120, over
    16 bits; out_bits = 16 clips them), in four push_many pieces, against the direct sums."""
    frames, want = big_case(mode, out_bits)
    eng = TdiEngine(stages=96, width=64, mode=mode, out_bits=out_bits, kernel=kernel)
    pieces = [
        as_block(eng.push_many(frames[a:b])) for a, b in ((0, 1), (1, 95), (95, 96), (96, 300))
    ]
    assert_same(concat_blocks(pieces), want, f"{kernel} {mode} {out_bits}")
    assert int(want.complete.sum()) == 300 - 95
    if mode == "sum" and out_bits is None:
        assert int(want.data.max()) > 65535  # the case really needs more than 16 bits
        twin = reference_lines(frames, range(300), 96)
        assert_same(twin, want, "twin")


LONG = [
    pytest.param({}, id="integer"),
    pytest.param({"rows_per_line": 1.07, "cols_per_line": -0.23, "reverse": True}, id="fractional"),
    pytest.param({"cols_per_line": 1, "mode": "mean"}, id="shift-mean"),
]


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("geometry", LONG)
def test_long_push_many_matches_direct(kernel: str, geometry: dict[str, Any]) -> None:
    """A long push_many (M = 64, N = 64, 3200 frames: every kernel's groups and edges many
    times over), after a short call and a lost frame, then single pushes: the same bits as the
    direct strided-diagonal sum; tdi_batch agrees with the engine fed in pieces."""
    m, n = 64, 64
    rows = rows_needed(
        m,
        float(geometry.get("rows_per_line", 1.0)),
        float(geometry.get("cols_per_line", 0.0)),
        bool(geometry.get("reverse", False)),
    )
    rng = np.random.default_rng(64)
    frames = rng.integers(0, 65536, size=(3210, rows, n), dtype=np.uint16)
    eng = TdiEngine(stages=m, width=n, kernel=kernel, **geometry)
    first = as_block(eng.push_many(frames[:5]))
    eng.gap(1)
    middle = as_block(eng.push_many(frames[5:3205]))
    last = stack_lines([eng.push(f) for f in frames[3205:]])
    got = concat_blocks([first, middle, last])
    index = [*range(5), *range(6, 3211)]
    want = reference_lines(frames, index, m, **geometry)
    assert_same(got, want, f"{kernel} long")
    # lines 6, 7, 8 have frames 0-4 and their own (and 7, 8 theirs since) but never frame 5
    assert got.stages_used[5:8].tolist() == [6, 7, 8]
    # the first complete line is 69: its stages 69 - 63 = 6 .. 69 are all after frame 5
    assert got.complete.tolist().index(True) == 68 and got.index[68] == 69
    whole, complete = tdi_batch(frames, m, kernel=kernel, **geometry)
    pieces = TdiEngine(stages=m, width=n, kernel=kernel, **geometry)
    parts = [as_block(pieces.push_many(frames[a:b])) for a, b in ((0, 1), (1, 2000), (2000, 3210))]
    assert np.array_equal(concat_blocks(parts).data, whole)
    assert np.array_equal(concat_blocks(parts).complete, complete)


@pytest.mark.parametrize("kernel", KERNELS)
def test_fractional_path_over_256_stages_does_not_overflow(kernel: str) -> None:
    """Fractional path, M = 300 > 256, full-scale 65535 frames: the sum in 1/W DN reaches
    300 * 65535 * 256 > 2^32 (the uint64 ring of docs/tdi.md). A constant scene interpolates
    exactly, so line k = min(k + 1, 300) * 65535 DN (sum) and 65535.0 (mean)."""
    m = 300
    speed = 1 + 1 / 8
    rows = rows_needed(m, speed)
    assert rows == 338  # y_299 = 336.375
    frames = np.full((m + 2, rows, 2), 65535, np.uint16)
    eng = TdiEngine(stages=m, width=2, rows_per_line=speed, kernel=kernel)
    got = as_block(eng.push_many(frames))
    used = np.minimum(np.arange(m + 2) + 1, m)
    assert got.data[:, 0].tolist() == (used * 65535).tolist()
    assert got.stages_used.tolist() == used.tolist()
    mean = TdiEngine(stages=m, width=2, rows_per_line=speed, kernel=kernel, mode="mean")
    assert np.all(as_block(mean.push_many(frames)).data == 65535.0)


@pytest.mark.parametrize("impl", [i for i in IMPLS if i != "reference"])
def test_a_drift_trim_keeps_the_open_lines_by_hand(impl: str) -> None:
    """set_drift(1) before frame 2 of M = 2 (the image loop's trim): stage 1 of line 2 was
    added from frame 1 without drift and stays; from frame 2 on each stage reads column
    j + i. S(3)[0] = f3[0,0] + f2[1,1]; S(3)[1] = f3[0,1] (column 2 is past the edge). No run
    restarts: every line from 1 on has both stages, unlike a change of M."""
    engine = TdiEngine(kernel=impl, stages=2, width=2)  # type: ignore[arg-type]
    lines = [engine.push(f) for f in HAND[:2]]
    engine.set_drift(1.0)
    lines += [engine.push(f) for f in HAND[2:]]
    got = stack_lines(lines)
    assert got.data.tolist() == [[1, 2], [13, 24], [130, 240], [1400, 2000], [4007, 9]]
    assert got.complete.tolist() == [False, True, True, True, True]
    assert engine.cols_per_line == 1.0
    with pytest.raises(ValueError, match="give a finite number of columns"):
        engine.set_drift(float("nan"))
