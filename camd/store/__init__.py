"""Recording: raw frames with their headers and metadata in HDF5 (``camd.store.recording``).

``camd.store.compression`` is imported first: it imports hdf5plugin, which registers the
compression filters with HDF5, so that every reader and writer of camd (all import this
package) opens compressed files.
"""

from camd.store import compression  # noqa: F401  (first: the filters registered)
from camd.store.recording import FORMAT, FORMAT_VERSION, FrameRecorder, RecordingError
from camd.store.recording_reading import Recording, read_recording

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "FrameRecorder",
    "Recording",
    "RecordingError",
    "read_recording",
]
