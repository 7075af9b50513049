"""Times as the history and events queries take them: ISO 8601, Unix seconds, ``now`` or a time
before now like ``-10m`` (docs/api.md, "Telemetry over time").

An ISO 8601 time without a zone is UTC: the archive's clock (``t_s``) is Unix time, and a
daemon's local zone is not something a client can see.
"""

from __future__ import annotations

import datetime as dt
import math
import re

from camd.daemon.errors import BadRequest

# Seconds per unit of a relative time ("-10m"): the units an operator types.
_UNIT_S = {"s": 1.0, "m": 60.0, "h": 3600.0, "d": 86400.0}
_RELATIVE = re.compile(r"^-(\d+(?:\.\d*)?|\.\d+)([smhd]?)$")
_HOW = (
    "give an ISO 8601 time (2026-11-27T22:00:00Z), a Unix time in seconds, now, or a time "
    "before now like -30s, -10m, -2h or -1d"
)


# The times a query may name: from the Unix epoch (the archive has nothing older) to the last
# second ISO 8601 can write (a time outside could not be said back in a message).
EARLIEST_S = 0.0
LATEST_S = 253_402_300_799.0  # 9999-12-31T23:59:59Z


def parse_instant(text: str, now_s: float, name: str) -> float:
    """The Unix time ``text`` names (``now_s`` for ``now`` and relative times); BadRequest
    naming the parameter ``name`` and the forms it takes otherwise, or if it is before 1970
    or after 9999."""
    t_s = _instant(text, now_s, name)
    if not EARLIEST_S <= t_s <= LATEST_S:
        raise BadRequest(
            f"{name}: {text!r} is {'before 1970' if t_s < EARLIEST_S else 'after 9999'}; give "
            "a time from 1970-01-01T00:00:00Z to 9999-12-31T23:59:59Z"
        )
    return t_s


def _instant(text: str, now_s: float, name: str) -> float:
    value = text.strip()
    if value.lower() == "now":
        return now_s
    relative = _RELATIVE.match(value)
    if relative is not None:
        return now_s - float(relative.group(1)) * _UNIT_S[relative.group(2) or "s"]
    try:
        unix_s = float(value)
    except ValueError:
        pass
    else:
        if math.isfinite(unix_s):
            return unix_s
        raise BadRequest(f"{name}: {text!r} is not a time; {_HOW}")
    try:
        when = dt.datetime.fromisoformat(value)
    except ValueError:
        raise BadRequest(f"{name}: {text!r} is not a time; {_HOW}") from None
    if when.tzinfo is None:
        when = when.replace(tzinfo=dt.UTC)
    return when.timestamp()


def iso_utc(t_s: float) -> str:
    """``t_s`` as ISO 8601 in UTC, to the second unless it has a fraction (``...Z``)."""
    when = dt.datetime.fromtimestamp(t_s, dt.UTC)
    spec = "seconds" if when.microsecond == 0 else "milliseconds"
    return when.replace(tzinfo=None).isoformat(timespec=spec) + "Z"


def parse_range(start: str, end: str, now_s: float) -> tuple[float, float]:
    """(start_s, end_s) of a query; BadRequest unless start is before end."""
    start_s = parse_instant(start, now_s, "start")
    end_s = parse_instant(end, now_s, "end")
    if not start_s < end_s:
        raise BadRequest(
            f"start ({start} = {iso_utc(start_s)}) is not before end ({end} = {iso_utc(end_s)}): "
            "give a start earlier than the end"
        )
    return start_s, end_s
