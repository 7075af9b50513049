"""The digital TDI engine: streaming (``TdiEngine``) and batch (``tdi_batch``).

docs/physics.md §1 (TAO12 eq 11): line k is ``sum_i frames[k - i][row_i]``, clipped per eq 12 or
averaged; docs/tdi.md states the exact arithmetic, the fractional (interpolated) taps and when a
line counts as complete. The engine holds a ring of M open partial sums (O(M x N) memory
whatever the scan length) and a short list of recent lost-frame ranges, so that ``push``,
``push_many`` and ``tdi_batch`` give the same bits however the frames are split into calls.

Kernels: ``kernel_numba`` (fused, compiled) or ``kernel_numpy`` (the plain reference). One
thread: the kernels are bound by memory bandwidth, and a second thread measured 0.97-1.04x of one
at the daemon's batch sizes (``camd bench tdi``), so the engine no longer splits blocks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal, TypedDict, Unpack

import numpy as np
import numpy.typing as npt

from camd.tdi import kernel_numpy
from camd.tdi.taps import StageTaps, stage_taps

Mode = Literal["sum", "mean"]
Kernel = Literal["auto", "numba", "numpy"]


def _numba_kernels() -> Any:
    """``camd.tdi.kernel_numba``, imported on first use (importing numba takes a while)."""
    from camd.tdi import kernel_numba

    return kernel_numba


def numba_available() -> bool:
    """True if the compiled kernels can be used (numba imports)."""
    try:
        import numba  # noqa: F401
    except ImportError:
        return False
    return True


@dataclass(frozen=True, slots=True)
class TdiLine:
    """One output line: ``data`` (N,), its ``index`` (= the frame's), the number of stages
    that contributed, and whether that is all M of them from consecutive frames."""

    data: npt.NDArray[Any]
    index: int
    stages_used: int
    complete: bool


@dataclass(frozen=True, slots=True)
class TdiBlock:
    """Output lines of a block of F frames: ``data`` (F, N), ``index`` (F,) int64,
    ``stages_used`` (F,) int32, ``complete`` (F,) bool."""

    data: npt.NDArray[Any]
    index: npt.NDArray[np.int64]
    stages_used: npt.NDArray[np.int32]
    complete: npt.NDArray[np.bool_]

    def __len__(self) -> int:
        return int(self.index.shape[0])


class TdiEngine:
    """Streaming digital TDI over window frames (docs/physics.md §1; contract in docs/tdi.md)."""

    def __init__(
        self,
        stages: int,
        width: int,
        *,
        mode: Mode = "sum",
        out_bits: int | None = None,
        rows_per_line: float = 1.0,
        cols_per_line: float = 0.0,
        reverse: bool = False,
        kernel: Kernel = "auto",
    ) -> None:
        if mode not in ("sum", "mean"):
            raise ValueError(f"mode must be 'sum' or 'mean', got {mode!r}")
        if out_bits is not None and (
            isinstance(out_bits, bool) or not isinstance(out_bits, int) or not 1 <= out_bits <= 32
        ):
            raise ValueError(f"out_bits = {out_bits!r}: give 1..32 output bits, or None (no clip)")
        if kernel not in ("auto", "numba", "numpy"):
            raise ValueError(f"kernel must be 'auto', 'numba' or 'numpy', got {kernel!r}")
        if kernel == "numba" and not numba_available():
            raise ValueError("kernel='numba' needs numba (pip install numba), or use 'numpy'")
        self.mode: Mode = mode
        self.out_bits = out_bits
        self.rows_per_line = float(rows_per_line)
        self.cols_per_line = float(cols_per_line)
        self.reverse = bool(reverse)
        self.kernel: Literal["numba", "numpy"] = (
            "numpy"
            if kernel == "numpy" or (kernel == "auto" and not numba_available())
            else "numba"
        )
        self._taps = self._make_taps(stages, width)
        self._prepare()
        self._acc = self._new_ring()
        self._next = 0
        self._run_start = 0
        self._lost: list[tuple[int, int]] = []  # [start, stop) of recent lost frame indices

    # -- configuration ------------------------------------------------------------------------

    def _make_taps(self, stages: int, width: int) -> StageTaps:
        return stage_taps(
            stages,
            width,
            rows_per_line=self.rows_per_line,
            cols_per_line=self.cols_per_line,
            reverse=self.reverse,
        )

    def _prepare(self) -> None:
        """What every kernel call of this configuration needs, worked out once: the kernel
        (whole rows; fractional rows; anything else) and its weights in the ring's type."""
        taps = self._taps
        acc_type = taps.accumulator
        if taps.shifted:
            self._path: Literal["integer", "rows", "general"] = "general"
        else:
            self._path = "integer" if taps.integer else "rows"
        self._row_weight = taps.row_weight.astype(acc_type)
        self._col_weight = taps.col_weight.astype(acc_type)
        # The row below each stage's (its weight is 0 where that row is not there).
        self._row_below = np.minimum(taps.row + 1, taps.rows_needed - 1)
        self._one = acc_type(taps.one)
        # _finish rounds by a shift: one must be a power of two (docs/tdi.md, 1/256 pixel).
        assert taps.one & (taps.one - 1) == 0, taps.one
        self._shift = taps.one.bit_length() - 1

    def _new_ring(self) -> npt.NDArray[Any]:
        return np.zeros((self._taps.stages, self._taps.width), dtype=self._taps.accumulator)

    @property
    def stages(self) -> int:
        """M, the number of stages summed into a line."""
        return self._taps.stages

    @stages.setter
    def stages(self, stages: int) -> None:
        """Change M between frames: a new run starts with the next frame, so the next M - 1
        lines are incomplete (nothing of the old run is mixed into them). The same M again
        changes nothing."""
        if stages == self._taps.stages:
            return
        self._taps = self._make_taps(stages, self._taps.width)
        self._prepare()
        self._acc = self._new_ring()
        self._run_start = self._next
        self._lost = []

    def set_drift(self, cols_per_line: float) -> None:
        """Follow ``cols_per_line`` columns of drift per line from the next frame (a trim while
        scanning): the open lines keep the partial sums they have, each later stage adds at the
        new drift, so nothing is lost (unlike a change of M). ValueError if not finite."""
        if not math.isfinite(cols_per_line):
            raise ValueError(f"cols_per_line = {cols_per_line}: give a finite number of columns")
        if float(cols_per_line) == self.cols_per_line:
            return
        self.cols_per_line = float(cols_per_line)
        self._taps = self._make_taps(self._taps.stages, self._taps.width)
        self._prepare()

    @property
    def width(self) -> int:
        """N, the columns of every frame and line."""
        return self._taps.width

    @property
    def rows_needed(self) -> int:
        """The fewest rows a frame must have for the current stages and taps."""
        return self._taps.rows_needed

    @property
    def next_index(self) -> int:
        """The line index the next pushed frame gets."""
        return self._next

    @property
    def valid_columns(self) -> slice:
        """Columns to which every stage contributes (fewer than N with a column shift)."""
        return self._taps.valid_columns()

    @property
    def state_bytes(self) -> int:
        """Memory the engine holds between calls: the ring of M partial sums."""
        return int(self._acc.nbytes)

    @property
    def taps(self) -> StageTaps:
        """Where each stage samples its frame (``camd.tdi.taps``)."""
        return self._taps

    # -- the stream ----------------------------------------------------------------------------

    def reset(self, index: int = 0) -> None:
        """Forget every open line; the next frame gets line index ``index``."""
        self._acc[:] = 0
        self._next = int(index)
        self._run_start = self._next
        self._lost = []

    def gap(self, n_frames: int) -> None:
        """``n_frames`` frames were lost before the next one: their indices are skipped, and
        every line they would have contributed to is incomplete."""
        if isinstance(n_frames, bool) or not isinstance(n_frames, int | np.integer):
            raise ValueError(f"gap needs a whole number of lost frames, got {n_frames!r}")
        if n_frames < 0:
            raise ValueError(f"gap of {n_frames} frames: the count of lost frames must be >= 0")
        if n_frames == 0:
            return
        stages = self._taps.stages
        start, stop = self._next, self._next + int(n_frames)
        # The lost frames' own lines never finish: empty their ring rows for the lines that
        # will reuse them.
        lost_lines = np.arange(start, min(stop, start + stages))
        self._acc[lost_lines % stages] = 0
        self._lost.append((start, stop))
        self._next = stop

    def push(self, frame: npt.NDArray[Any]) -> TdiLine:
        """One window frame (rows, N) in, its line out (the same bits as ``push_many`` of one
        frame, with less done per call: a live stream calls this at the frame rate)."""
        arr = np.asarray(frame)
        if arr.ndim != 2:
            raise ValueError(
                f"push takes one frame of shape (rows, {self.width}), got shape {arr.shape}; "
                "use push_many for a stack of frames"
            )
        index = self._next
        raw = self._run(self._checked(arr[np.newaxis]), self._acc, index)
        used = self._stages_used_by(index)
        self._next = index + 1
        if self._lost:
            self._prune_lost()
        return TdiLine(
            data=self._finish(raw, used)[0],
            index=index,
            stages_used=used,
            complete=used == self._taps.stages,
        )

    def push_many(self, frames: npt.NDArray[Any]) -> TdiBlock:
        """F window frames (F, rows, N) in, their F lines out (same bits as F ``push`` calls)."""
        stack = self._checked(frames)
        count = stack.shape[0]
        first = self._next
        raw = self._run(stack, self._acc, first)
        index = np.arange(first, first + count, dtype=np.int64)
        used = self._stages_used(index)
        self._next = first + count
        self._prune_lost()
        return TdiBlock(
            data=self._finish(raw, used),
            index=index,
            stages_used=used,
            complete=used == self._taps.stages,
        )

    # -- internals ----------------------------------------------------------------------------

    def _checked(self, frames: npt.NDArray[Any]) -> npt.NDArray[np.uint16]:
        arr = np.asarray(frames)
        if arr.ndim != 3:
            raise ValueError(
                f"push_many takes frames of shape (F, rows, {self.width}), got shape {arr.shape}"
            )
        if arr.shape[2] != self.width:
            raise ValueError(
                f"frames are {arr.shape[2]} columns wide but the engine was made for "
                f"width = {self.width}; make a new engine for this window"
            )
        if arr.shape[1] < self.rows_needed:
            raise ValueError(
                f"frames have {arr.shape[1]} rows but {self.stages} stages at rows_per_line = "
                f"{self.rows_per_line:g} need {self.rows_needed}; use fewer stages or a taller "
                "window"
            )
        if arr.dtype != np.uint16:
            if not np.issubdtype(arr.dtype, np.integer) or not np.can_cast(arr.dtype, np.uint16):
                raise ValueError(
                    f"frames must be uint16 pixels (or a narrower unsigned integer type), "
                    f"got {arr.dtype}"
                )
            arr = arr.astype(np.uint16)
        return np.ascontiguousarray(arr)

    def _run(
        self, frames: npt.NDArray[np.uint16], ring: npt.NDArray[Any], first: int
    ) -> npt.NDArray[Any]:
        taps = self._taps
        if self.kernel == "numpy":
            return kernel_numpy.accumulate(frames, ring, taps, first)
        kernels = _numba_kernels()
        out = np.empty((frames.shape[0], taps.width), dtype=ring.dtype)
        if self._path == "integer":
            kernels.integer_rows(frames, ring, out, taps.row, first)
        elif self._path == "rows":
            kernels.fractional_rows(
                frames, ring, out, taps.row, self._row_below, self._row_weight, self._one, first
            )
        else:
            kernels.general(
                frames,
                ring,
                out,
                taps.row,
                self._row_weight,
                taps.col,
                self._col_weight,
                self._one,
                first,
            )
        return out

    def _stages_used(self, index: npt.NDArray[np.int64]) -> npt.NDArray[np.int32]:
        """Stages present for each line: frames of the current run within the last M, less
        those lost (docs/tdi.md, completeness)."""
        stages = self._taps.stages
        lo = np.maximum(index - (stages - 1), self._run_start)
        used = index - lo + 1
        for start, stop in self._lost:
            overlap = np.minimum(stop, index + 1) - np.maximum(start, lo)
            used -= np.clip(overlap, 0, None)
        return used.astype(np.int32)

    def _stages_used_by(self, index: int) -> int:
        """``_stages_used`` of one line, in plain integers (``push``)."""
        lo = max(index - (self._taps.stages - 1), self._run_start)
        used = index - lo + 1
        for start, stop in self._lost:
            used -= max(0, min(stop, index + 1) - max(start, lo))
        return used

    def _prune_lost(self) -> None:
        horizon = self._next - self._taps.stages
        self._lost = [(a, b) for a, b in self._lost if b > horizon]

    def _finish(self, raw: npt.NDArray[Any], used: npt.NDArray[np.int32] | int) -> npt.NDArray[Any]:
        """Raw sums (in 1/one DN; ``raw`` is the kernel's own output, changed in place) to the
        output: clipped uint32 sums or float32 means."""
        one = self._taps.one
        if self.mode == "mean":
            scale = np.asarray(used, dtype=np.float64).reshape(-1, 1) * one
            mean: npt.NDArray[Any] = (raw / scale).astype(np.float32)
            return mean
        if one != 1:
            # round half up: (raw + one / 2) // one, one being a power of two
            np.add(raw, one // 2, out=raw)
            np.right_shift(raw, self._shift, out=raw)
        if self.out_bits is not None:
            np.minimum(raw, (1 << self.out_bits) - 1, out=raw)
        result: npt.NDArray[Any] = raw.astype(np.uint32, copy=False)
        return result


class TdiOptions(TypedDict, total=False):
    """``TdiEngine``'s keyword arguments, for ``tdi_batch``, which passes them on: each default
    stays written once, in ``TdiEngine``."""

    mode: Mode
    out_bits: int | None
    rows_per_line: float
    cols_per_line: float
    reverse: bool
    kernel: Kernel


def tdi_batch(
    frames: npt.NDArray[Any], stages: int, **options: Unpack[TdiOptions]
) -> tuple[npt.NDArray[Any], npt.NDArray[np.bool_]]:
    """TDI of a whole stack of frames (F, rows, N) at once: ``(lines (F, N), complete (F,))``.

    The same bits as a new ``TdiEngine`` fed the same frames (docs/tdi.md).
    """
    arr = np.asarray(frames)
    if arr.ndim != 3:
        raise ValueError(f"tdi_batch takes frames of shape (F, rows, N), got shape {arr.shape}")
    block = TdiEngine(stages, arr.shape[2], **options).push_many(arr)
    return block.data, block.complete


def warm_up() -> float:
    """Load (or compile) every kernel the engine can call, on tiny frames: the integer and the
    interpolating kernels, with 32- and 64-bit accumulators, in ``push_many`` and ``push``.
    Numba compiles a kernel on its first call for each argument type, a second or more per
    kernel; a daemon calls this at start, on a thread of its own, so that the first scan does
    not wait for it. Returns the seconds it took (about 0 once done)."""
    import time

    t0 = time.perf_counter()
    if numba_available():
        for stages, rows_per_line, cols_per_line in (
            (2, 1.0, 0.0),
            (2, 1.5, 0.0),
            (2, 1.0, 0.5),
            (300, 1.5, 0.0),  # over 256 stages: the 64-bit ring (docs/tdi.md)
            (300, 1.0, 0.5),
        ):
            engine = TdiEngine(
                stages,
                4,
                rows_per_line=rows_per_line,
                cols_per_line=cols_per_line,
                kernel="numba",
            )
            frames = np.zeros((2, engine.rows_needed, 4), dtype=np.uint16)
            engine.push_many(frames)
            engine.push(frames[0])
    return time.perf_counter() - t0
