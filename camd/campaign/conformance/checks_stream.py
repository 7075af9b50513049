"""Stream checks: headers, counters, CRCs and the frame period of a short stream
(docs/stream.md "Frame format (version 1)", docs/sensors.md §1 "[timing]").

Each check takes its own short stream of a small window (restored afterwards), so that each
stands alone, and reads the headers the daemon kept of it (GET /api/v1/stream/headers, which
keeps the headers of frames the payload CRC rejected too): the header, counter and period
checks therefore do not depend on the CRCs being right, nor on each other.
"""

from __future__ import annotations

import contextlib
import itertools
import statistics
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

from camd.client import CamdError
from camd.client_types import StreamFrameHeader, StreamResponse
from camd.protocol.stream import FrameFlags

from .engine import CheckFailed, CheckNotRun, Evidence, Unit, check_function, conclude
from .raw import ack_values

STREAM_FRAMES = 12  # enough differences for a median period, few enough to be quick
WINDOW_ROWS = 16  # a small window: frames of tens of kB, periods well under a millisecond
# The specs state no tolerance for the frame period. 1 % is far outside a crystal clock's
# error (tens of ppm) and the timestamps' 1 ns rounding, and far inside a wrong period.
PERIOD_TOLERANCE = 0.01
KNOWN_FLAGS = int(
    FrameFlags.BINNED_2X2 | FrameFlags.TEST_PATTERN | FrameFlags.SATURATED
    | FrameFlags.DEVICE_OVERFLOW | FrameFlags.LAST
)  # fmt: skip


NO_FRAME_DEVICE = "no_frame_device"
"""The daemon's error code (503) for an acquisition whose frame-stream device is missing or
cannot be opened while the command link answers (docs/api.md). A camera that drops off the
link (503 ``disconnected``) is not "no stream": the check fails with the daemon's message."""


@contextlib.contextmanager
def frame_stream_used() -> Iterator[None]:
    """Around the request that starts an acquisition: a daemon that cannot open the frame
    stream (503 ``no_frame_device``) makes the check not run for want of a stream (CheckNotRun), not fail:
    the unit was not shown wrong, only not shown at all."""
    try:
        yield
    except CamdError as exc:
        if exc.code == NO_FRAME_DEVICE:
            raise CheckNotRun("stream", exc.message, {"code": exc.code}) from None
        raise


@dataclass(frozen=True)
class ShortStream:
    response: StreamResponse
    headers: list[StreamFrameHeader]
    frame_period_s: float  # what the registers set (GET /api/v1/timing)
    window_rows: int
    earlier_headers: int  # headers in the log of frames before this stream's first counter


def short_stream(unit: Unit, frames: int = STREAM_FRAMES) -> ShortStream:
    """Stream ``frames`` area-mode frames of a WINDOW_ROWS window; mode, window and the
    link's training as they were afterwards (the link is trained first if it is not)."""
    client = unit.client
    mode = client.status()["mode"]
    rows_before = int(client.timing()["window_rows"])
    if ack_values(unit, "GET_SENSOR")["trained"] != "yes":
        client.train()
    rows = min(WINDOW_ROWS, rows_before)
    written = unit.regmap.role_write("window_rows", rows)
    try:
        if written is not None:
            client.write_registers({written[0]: written[1]})
        period_s = float(client.timing()["frame_period_s"])
        with frame_stream_used():
            response = client.acquire(frames, mode="area", timeout_s=30.0)
        log = client.stream_headers()["frames"]
    finally:
        back = unit.regmap.role_write("window_rows", rows_before)
        if written is not None and back is not None:
            client.write_registers({back[0]: back[1]})
        if mode is not None and client.status()["mode"] != mode:
            client.set_mode(mode)
    # A frame belongs to this stream by its device counter: one counted before the first that
    # START_STREAM announced is an earlier stream's, come late, and not this unit's answer.
    first = int(response["first_counter"])
    headers = [h for h in log if (h["counter"] - first) % 2**32 < 2**31]
    return ShortStream(response, headers, period_s, rows, len(log) - len(headers))


def _brief(h: StreamFrameHeader) -> dict[str, Any]:
    return {k: h[k] for k in ("counter", "timestamp_ns", "line_period_ns", "rows", "cols",
                              "bits", "mode", "stages", "flags", "payload_bytes")}  # fmt: skip


@check_function("stream_headers")
def stream_headers_check(unit: Unit) -> Evidence:
    """Every frame's header agrees with the stream and the registers: window size, bits,
    mode, stages, payload size, the line period the registers set, only defined flags, LAST
    on the last frame only."""
    s = short_stream(unit)
    r = s.response
    expected_ns = round(s.frame_period_s * 1e9)
    evidence: Evidence = {
        "frames_requested": STREAM_FRAMES,
        "headers_received": len(s.headers),
        "stream": {k: r[k] for k in ("mode", "rows", "cols", "bits", "stages")},
        "register_frame_period_ns": expected_ns,
        "headers": [_brief(h) for h in s.headers[:4]],
        "headers_of_earlier_streams": s.earlier_headers,
    }
    problems: list[str] = []
    if len(s.headers) != STREAM_FRAMES:
        problems.append(f"{len(s.headers)} headers received of {STREAM_FRAMES} frames")
    for i, h in enumerate(s.headers):
        last = i == len(s.headers) - 1
        wrong = {
            "rows": h["rows"] != r["rows"] or h["rows"] != s.window_rows,
            "cols": h["cols"] != r["cols"],
            "bits": h["bits"] != r["bits"],
            "mode": h["mode"] != "area",
            "stages": h["stages"] != 0,
            "payload_bytes": h["payload_bytes"] != h["rows"] * h["cols"] * 2,
            "line_period_ns": abs(h["line_period_ns"] - expected_ns) > 1,
            "flags": bool(h["flags"] & ~KNOWN_FLAGS) or bool(h["flags"] & FrameFlags.LAST) != last,
        }
        bad = [name for name, is_bad in wrong.items() if is_bad]
        if bad:
            problems.append(f"frame {i} (counter {h['counter']}): {', '.join(bad)} wrong")
            evidence.setdefault("wrong_headers", []).append(_brief(h))
    return conclude(problems[:5], evidence)


@check_function("stream_counters")
def stream_counters_check(unit: Unit) -> Evidence:
    """Frame counters go up by exactly one per frame from the first counter START_STREAM
    announced, the host counts none lost, and the device made as many as asked."""
    s = short_stream(unit)
    counters = [h["counter"] for h in s.headers]
    steps = [(b - a) % 2**32 for a, b in itertools.pairwise(counters)]
    stats = s.response["stats"]
    evidence: Evidence = {
        "first_counter_announced": s.response["first_counter"],
        "counters": counters,
        "frames_sent_by_device": s.response["frames_sent"],
        "host_lost": stats["lost"],
        "host_out_of_order": stats["out_of_order"],
    }
    problems = []
    if counters and counters[0] != s.response["first_counter"]:
        problems.append(
            f"first counter {counters[0]}, START_STREAM said {s.response['first_counter']}"
        )
    jumps = [(i, step) for i, step in enumerate(steps) if step != 1]
    if jumps:
        problems.append(
            "counter steps other than 1: "
            + ", ".join(f"{counters[i]} -> {counters[i + 1]}" for i, _ in jumps[:5])
        )
    if stats["lost"] or stats["out_of_order"]:
        problems.append(f"host counted {stats['lost']} lost, {stats['out_of_order']} out of order")
    if s.response["frames_sent"] != STREAM_FRAMES or len(counters) != STREAM_FRAMES:
        problems.append(
            f"device sent {s.response['frames_sent']}, host saw {len(counters)} headers, of "
            f"{STREAM_FRAMES} asked"
        )
    return conclude(problems, evidence)


@check_function("stream_crc")
def stream_crc_check(unit: Unit) -> Evidence:
    """Every frame's payload CRC-32 (zlib's, docs/stream.md) matches the payload the host
    received, and the host counted no corrupt frame (header CRCs included)."""
    s = short_stream(unit)
    pairs = [(h["counter"], h["payload_crc32"], h["payload_crc32_host"]) for h in s.headers]
    mismatched = [p for p in pairs if p[1] != p[2]]
    stats = s.response["stats"]
    evidence: Evidence = {
        "frames": len(pairs),
        "host_corrupt": stats["corrupt"],
        "crcs": [
            {"counter": c, "header": f"0x{a:08X}", "computed": f"0x{b:08X}"}
            for c, a, b in (mismatched or pairs)[:6]
        ],
        "mismatched": len(mismatched),
    }
    if mismatched or stats["corrupt"] or not pairs:
        raise CheckFailed(
            f"{len(mismatched)} of {len(pairs)} payload CRCs differ from the payload's CRC-32; "
            f"the host counted {stats['corrupt']} corrupt",
            evidence,
        )
    return evidence


@check_function("frame_period")
def frame_period_check(unit: Unit) -> Evidence:
    """The frames' timestamps are one frame period apart, the period the registers set
    (GET /api/v1/timing: (n + k + 1) T_line, docs/physics.md §2), within PERIOD_TOLERANCE."""
    s = short_stream(unit)
    stamps = [h["timestamp_ns"] for h in s.headers]
    # Consecutive frames as received: a skipped counter or a rejected payload does not matter.
    diffs = [b - a for a, b in itertools.pairwise(stamps)]
    expected_s = s.frame_period_s
    evidence: Evidence = {
        "register_frame_period_s": expected_s,
        "timestamp_differences_ns": diffs[:11],
        "tolerance": PERIOD_TOLERANCE,
    }
    if not diffs:
        raise CheckFailed(f"{len(stamps)} frames: no period to measure", evidence)
    measured_s = statistics.median(diffs) * 1e-9
    error = measured_s / expected_s - 1.0
    evidence |= {"measured_frame_period_s": measured_s, "relative_error": error}
    if abs(error) > PERIOD_TOLERANCE:
        raise CheckFailed(
            f"frame period {measured_s * 1e3:.6f} ms, the registers set {expected_s * 1e3:.6f} ms "
            f"({error:+.2%}, tolerance {PERIOD_TOLERANCE:.0%})",
            evidence,
        )
    return evidence
