"""Recording: raw frames with their headers and metadata in HDF5 (``camd.store.recording``)."""

from camd.store.recording import (
    FORMAT,
    FORMAT_VERSION,
    FrameRecorder,
    Recording,
    RecordingError,
    read_recording,
)

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "FrameRecorder",
    "Recording",
    "RecordingError",
    "read_recording",
]
