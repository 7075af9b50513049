"""How camd's writers compress what they store: the filters as data, checked, and the options
they give h5py.

Both writers (``camd.store.recording.FrameRecorder``'s ``/frames``, one chunk per frame, and
``camd.store.tdi_recording.TdiRecorder``'s ``/lines``, one chunk per block of lines) take a
``Compression``: a filter of ``FILTERS`` and, for the filters that have one, a level. The
default, ``DEFAULT``, was chosen by measurement on the simulator's frames and TDI sums
(``camd bench store``; docs/stream.md, "Compression"): Bitshuffle + LZ4, the filter the field's
detector files use, at about 2.4x on the default flat scene, within 5 % of the best filter
measured on the bar target, and several times hr400's full-window data rate (200 MB/s) on one
core. The filters are lossless: every file reads back bit-exact.

The HDF5 filters beyond gzip and lzf come from hdf5plugin, which registers them with the HDF5
library when it is imported: this module imports it, and ``camd.store``'s ``__init__`` imports
this module, so that any code that imports anything of ``camd.store`` (every camd reader and
writer) can open a compressed file. Other programs need ``import hdf5plugin`` before they open
one with h5py (docs/stream.md, "Compression").

What a compressed chunk may take on disk: incompressible data (noise over the whole range)
comes out slightly larger than it went in (each filter's header and per-block overhead), so
the space a writer asks its ``Headroom`` for before a write is ``chunk_bound_bytes``, not the
chunk's raw size.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import hdf5plugin

__all__ = [
    "DEFAULT",
    "FILTERS",
    "OFF",
    "Compression",
    "CompressionFilter",
    "check_level",
    "check_name",
    "chunk_bound_bytes",
    "filtered_bound_bytes",
]

OFF = "off"


@dataclass(frozen=True, slots=True)
class CompressionFilter:
    """One choice of ``FILTERS``: what it is, the h5py ``create_dataset`` keyword arguments it
    makes for a level (``make``, given the level or, for a filter without levels, 0), its levels
    (None: it has none) and its default level."""

    name: str
    description: str
    make: Callable[[int], dict[str, Any]]
    levels: tuple[int, int] | None = None  # the lowest and highest level
    default_level: int | None = None

    def options(self, level: int | None) -> dict[str, Any]:
        """The keyword arguments of h5py's ``create_dataset`` that make a dataset compressed
        with this filter at ``level`` (None: its default; checked by ``Compression.of``)."""
        return self.make(level if level is not None else self.default_level or 0)


# Every choice, in the order the errors and the docs list them: "off" first, the default next.
FILTERS: dict[str, CompressionFilter] = {
    f.name: f
    for f in (
        CompressionFilter(
            OFF,
            "no compression: the chunks as they are (the fastest, the largest)",
            lambda _: {},
        ),
        CompressionFilter(
            "bitshuffle-lz4",
            "Bitshuffle then LZ4 (hdf5plugin, HDF5 filter 32008): the field's detector files' "
            "filter",
            lambda _: dict(hdf5plugin.Bitshuffle(cname="lz4")),
        ),
        CompressionFilter(
            "bitshuffle-zstd",
            "Bitshuffle then Zstandard (hdf5plugin, HDF5 filter 32008)",
            lambda level: dict(hdf5plugin.Bitshuffle(cname="zstd", clevel=level)),
            levels=(1, 22),
            default_level=1,
        ),
        CompressionFilter(
            "blosc2-zstd",
            "Blosc2 with byte shuffle and Zstandard (hdf5plugin, HDF5 filter 32026)",
            lambda level: dict(
                hdf5plugin.Blosc2(cname="zstd", clevel=level, filters=hdf5plugin.Blosc2.SHUFFLE)
            ),
            levels=(1, 9),
            default_level=1,
        ),
        CompressionFilter(
            "gzip",
            "byte shuffle then deflate (built into HDF5; slow)",
            lambda level: {"compression": "gzip", "compression_opts": level, "shuffle": True},
            levels=(1, 9),
            default_level=1,
        ),
        CompressionFilter(
            "lzf",
            "byte shuffle then LZF (built into h5py)",
            lambda _: {"compression": "lzf", "shuffle": True},
        ),
    )
}


def _choices() -> str:
    return ", ".join(repr(name) for name in FILTERS)


@dataclass(frozen=True, slots=True)
class Compression:
    """A filter of ``FILTERS`` and its level (None: the filter's default, or it has none).
    Make one with ``of``, which checks both."""

    filter: str
    level: int | None = None

    @classmethod
    def of(cls, name: object, level: object = None) -> Compression:
        """The compression ``name`` at ``level`` (None: the filter's default), checked;
        ValueError naming the valid choices (of filter, or of level for this filter)."""
        if not isinstance(name, str) or name not in FILTERS:
            raise ValueError(f"unknown compression {name!r}: choose one of {_choices()}")
        spec = FILTERS[name]
        if level is None:
            return cls(name, spec.default_level)
        if isinstance(level, bool) or not isinstance(level, int):
            raise ValueError(f"compression level {level!r} must be a whole number")
        if spec.levels is None:
            raise ValueError(
                f"compression {name!r} has no levels: leave the level out (or choose a filter "
                "with levels: " + ", ".join(f"{n!r} {lo}..{hi}" for n, (lo, hi) in _leveled()) + ")"
            )
        lo, hi = spec.levels
        if not lo <= level <= hi:
            raise ValueError(
                f"compression level {level} is out of range for {name!r}: choose {lo}..{hi} "
                f"(default {spec.default_level})"
            )
        return cls(name, level)

    @property
    def on(self) -> bool:
        """Whether the data are compressed at all."""
        return self.filter != OFF

    def dataset_options(self) -> dict[str, Any]:
        """h5py ``create_dataset`` keyword arguments for a chunked dataset of this compression."""
        return FILTERS[self.filter].options(self.level)

    def attrs(self) -> dict[str, Any]:
        """What a compressed dataset says of itself, as attributes: ``compression`` (the
        filter's name, or "off") and ``compression_level`` (when the filter has levels)."""
        values: dict[str, Any] = {"compression": self.filter}
        if self.level is not None:
            values["compression_level"] = self.level
        return values

    def describe(self) -> str:
        """The filter and its level, for messages: ``blosc2-zstd level 1``, ``off``."""
        return self.filter if self.level is None else f"{self.filter} level {self.level}"


def check_name(name: str | None) -> str | None:
    """A config's or a request's ``compression`` (None: not given), checked: ValueError naming
    the valid choices."""
    if name is not None:
        Compression.of(name)
    return name


def check_level(name: str | None, level: int | None) -> int | None:
    """A config's or a request's ``compression_level`` (None: not given) for the filter
    ``name`` (None: not given), checked: ValueError saying which levels that filter takes."""
    if level is not None:
        if name is None:
            raise ValueError(
                "compression_level needs compression: name the filter it is a level of "
                f"(one of {_choices()})"
            )
        Compression.of(name, level)
    return level


def _leveled() -> list[tuple[str, tuple[int, int]]]:
    """The filters that have levels, with their lowest and highest."""
    return [(n, f.levels) for n, f in FILTERS.items() if f.levels is not None]


DEFAULT = Compression.of("bitshuffle-lz4")
"""The compression recordings and scans get unless the config or the request says otherwise."""


def chunk_bound_bytes(raw_bytes: int, compression: Compression) -> int:
    """The most one chunk of ``raw_bytes`` may take on disk compressed with ``compression``:
    its raw size when off, else ``filtered_bound_bytes``."""
    return filtered_bound_bytes(raw_bytes) if compression.on else raw_bytes


def filtered_bound_bytes(raw_bytes: int) -> int:
    """The most one chunk of ``raw_bytes`` may take on disk through any filter of ``FILTERS``:
    above every filter's worst case on incompressible data (LZ4's is 1/255 more plus 16 bytes
    a block, deflate's 5 bytes a 16 KiB block, Blosc2's and Bitshuffle's headers a few dozen
    bytes; an lzf output larger than its input is stored raw), with room to spare."""
    return raw_bytes + raw_bytes // 64 + (64 << 10)
