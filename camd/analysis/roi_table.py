"""ROI statistics of one frame as a CSV table, one ROI a row (docs/live-view.md, "Snapshots").

The daemon answers it (``GET /api/v1/live/snapshot/roi.csv``) and ``camctl snapshot`` writes it
from a snapshot TIFF's metadata: one writer, so that both give the same table.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Mapping, Sequence
from typing import Any

from camd.analysis.roi import STAT_FIELDS

RECT_FIELDS = ("x", "y", "width", "height")

ROI_CSV_COLUMNS = ("roi", *RECT_FIELDS, "counter", "timestamp_ns", *STAT_FIELDS)
"""The table's header: the ROI, its rectangle, the frame, then the statistics (DN)."""


def roi_csv(
    counter: int,
    timestamp_ns: int,
    stats: Mapping[str, Mapping[str, Any]],
    rois: Sequence[Mapping[str, Any]],
) -> str:
    """The statistics ``stats`` (ROI name -> ``STAT_FIELDS`` values) of the frame ``counter``,
    one ROI a row, their rectangles from ``rois``; an empty cell where a statistic is not
    defined (None: the SNR of a flat ROI, the background-subtracted mean without one)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(ROI_CSV_COLUMNS)
    where = {r["name"]: r for r in rois}
    for name, values in stats.items():
        rect = where.get(name, {})
        writer.writerow(
            [
                name,
                *(rect.get(k, "") for k in RECT_FIELDS),
                counter,
                timestamp_ns,
                *("" if values[k] is None else repr(values[k]) for k in STAT_FIELDS),
            ]
        )
    return out.getvalue()
