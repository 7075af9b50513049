"""camctl's human output: values, times and states as text, and the tables of the device's state.

``camctl_device`` prints its commands with these (status, ping, link, telemetry and history,
events, control, emergency stop), and ``camd demo`` shows the same tables. A value the daemon
sent goes into a table as plain text (``cell``), never read as rich markup. With ``--json``
none of this runs: the API's document is printed as it is.
"""

from __future__ import annotations

import json
import time
from itertools import zip_longest
from typing import Any

from rich import box
from rich.table import Table
from rich.text import Text

STATE_STYLE = {
    "idle": "bold green",
    "staring": "bold cyan",
    "scanning": "bold cyan",
    "imaging": "bold cyan",
    "disconnected": "bold yellow",
    "fault": "bold red",
}
LIMIT_STYLE = {"ok": "green", "yellow": "bold yellow", "red": "bold red"}
LEVEL_STYLE = {"info": "", "warning": "yellow", "warn": "yellow", "error": "red", "critical": "red"}


def cell(value: Any) -> Text:
    """A table cell holding a value the daemon sent: text, never read as rich markup (a reason
    or an event that says "[sim] profile = ..." keeps its brackets)."""
    return Text(fmt_value(value))


def fmt_value(value: Any) -> str:
    """A compact human form of a JSON value (6 significant digits for floats)."""
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return format(value, ".6g")
    if isinstance(value, dict | list):
        return json.dumps(value)
    return str(value)


def fmt_time(t_s: Any) -> str:
    """Wall-clock seconds as local HH:MM:SS.mmm; other numbers (relative times) as seconds."""
    if not isinstance(t_s, int | float):
        return fmt_value(t_s)
    if t_s > 1e9:  # seconds since the epoch
        return time.strftime("%H:%M:%S", time.localtime(t_s)) + f".{int(t_s * 1000) % 1000:03d}"
    return f"{t_s:.3f} s"


def fmt_firmware(version: Any) -> str:
    """GET_STATUS fw_version (major * 256 + minor) as ``major.minor``."""
    if isinstance(version, int) and not isinstance(version, bool):
        return f"{version >> 8}.{version & 0xFF}"
    return fmt_value(version)


def state_text(state: Any) -> Text:
    """The daemon state, coloured."""
    return Text(str(state), style=STATE_STYLE.get(str(state), "bold"))


def limit_text(limit: Any) -> Text:
    """A telemetry limit state (ok / yellow / red), coloured."""
    return Text(str(limit), style=LIMIT_STYLE.get(str(limit), ""))


def _kv_table(title: str | None = None) -> Table:
    table = Table(
        title=title, box=box.SIMPLE_HEAVY, show_edge=False, show_header=False, title_justify="left"
    )
    table.add_column("key", style="dim")
    table.add_column("value")
    return table


def backends_text(backends: dict[str, Any]) -> Text:
    """``hardware: link serial /dev/ttyUSB0, stream libusb USB 04b4:00f1, registers fpga (...)``;
    a mix of simulated and real interfaces in yellow."""
    parts = [
        f"{name} {part.get('backend')} {part.get('detail')}"
        if name != "registers"
        else f"{name} {part.get('backend')} ({part.get('detail')})"
        for name in ("link", "stream", "registers")
        if isinstance(part := backends.get(name), dict)
    ]
    camera = str(backends.get("camera"))
    return Text(f"{camera}: " + ", ".join(parts), style="yellow" if camera == "mixed" else "")


def status_table(doc: dict[str, Any], title: str | None = "camd status") -> Table:
    """The status document as a two-column table, state coloured."""
    table = _kv_table(title)
    table.add_row("state", state_text(doc.get("state")))
    if doc.get("reason"):
        table.add_row("reason", cell(doc.get("reason")))
    table.add_row("mode", fmt_value(doc.get("mode")))
    link = doc.get("link") or {}
    connected = link.get("connected")
    table.add_row(
        "link",
        Text.assemble(
            f"{link.get('port', '-')} ",
            ("connected", "green") if connected else ("not connected", "yellow"),
        ),
    )
    if link.get("last_error"):
        table.add_row("link error", Text(str(link["last_error"]), style="yellow"))
    if link.get("sim_state") is not None:  # the simulated camera this daemon spawned
        sim_state = str(link["sim_state"])
        table.add_row(
            "simulator",
            Text(
                f"{sim_state}, pid {link.get('sim_pid') or '-'}, "
                f"restarts {link.get('sim_restarts') or 0}",
                style="green" if sim_state == "running" else "yellow",
            ),
        )
    if isinstance(doc.get("backends"), dict):
        table.add_row("camera", backends_text(doc["backends"]))
    device = doc.get("device")
    if isinstance(device, dict):
        for key, value in device.items():
            shown = fmt_firmware(value) if key == "fw_version" else fmt_value(value)
            table.add_row(f"device.{key}", shown)
    else:
        table.add_row("device", "-")
    daemon = doc.get("daemon") or {}
    for key, value in daemon.items():
        table.add_row(f"daemon.{key}", cell(value))
    if isinstance(doc.get("estop"), dict) and doc["estop"].get("latched"):
        table.add_row("EMERGENCY STOP", estop_text(doc["estop"]))
    if isinstance(doc.get("control"), dict):
        table.add_row("control", control_text(doc["control"]))
    acquisition = doc.get("acquisition")
    if isinstance(acquisition, dict):
        running = "running" if acquisition.get("running") else "ended"
        by = f" by {acquisition['client']}" if acquisition.get("client") else ""
        table.add_row(
            "acquisition",
            f"{acquisition.get('kind')} {running}: {acquisition.get('description')}{by}, "
            f"since {fmt_time(acquisition.get('started_t_s'))}",
        )
    listed = {
        "state", "reason", "mode", "link", "device", "daemon", "control", "acquisition", "estop",
    }  # fmt: skip
    for key, value in doc.items():
        if key not in listed:
            table.add_row(key, cell(value))
    return table


def ping_table(doc: dict[str, Any], title: str | None = "ping") -> Table:
    """A ping result: counts and RTT percentiles."""
    table = _kv_table(title)
    failed = doc.get("failed", 0)
    table.add_row("count", fmt_value(doc.get("count")))
    table.add_row("ok", Text(fmt_value(doc.get("ok")), style="green"))
    table.add_row("failed", Text(fmt_value(failed), style="bold red" if failed else "green"))
    table.add_row("retries", fmt_value(doc.get("retries")))
    rtt = doc.get("rtt_ms") or {}
    for key in ("p50", "p99", "max"):
        value = rtt.get(key)
        shown = f"{value:.3f} ms" if isinstance(value, int | float) else fmt_value(value)
        table.add_row(f"rtt {key}", shown)
    for key, value in doc.items():
        if key not in {"count", "ok", "failed", "retries", "rtt_ms", "errors"}:
            table.add_row(key, cell(value))
    return table


def _flatten(doc: dict[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    rows: list[tuple[str, Any]] = []
    for key, value in doc.items():
        if isinstance(value, dict):
            rows += _flatten(value, f"{prefix}{key}.")
        else:
            rows.append((f"{prefix}{key}", value))
    return rows


def link_table(doc: dict[str, Any], title: str | None = "command link counters") -> Table:
    """Host and device counters side by side."""
    table = Table(title=title, box=box.SIMPLE_HEAVY, show_edge=False, title_justify="left")
    table.add_column("host", style="dim")
    table.add_column("", justify="right")
    table.add_column("device", style="dim")
    table.add_column("", justify="right")
    host = _flatten(doc.get("host") or {})
    device_doc = doc.get("device")
    device = _flatten(device_doc) if isinstance(device_doc, dict) else [("(disconnected)", None)]
    for (hk, hv), (dk, dv) in zip_longest(host, device, fillvalue=("", "")):
        table.add_row(hk, cell(hv) if hk else "", dk, cell(dv) if dk else "")
    return table


def telemetry_table(doc: dict[str, Any], title: str | None = "telemetry") -> Table:
    """Latest value of every channel with its unit and limit state."""
    table = Table(title=title, box=box.SIMPLE_HEAVY, show_edge=False, title_justify="left")
    table.add_column("channel")
    table.add_column("value", justify="right")
    table.add_column("unit")
    table.add_column("limit")
    table.add_column("time")
    latest = doc.get("latest") or {}
    for name, sample in latest.items():
        table.add_row(
            name,
            fmt_value(sample.get("value")),
            fmt_value(sample.get("unit")) if sample.get("unit") else "",
            limit_text(sample.get("limit")),
            fmt_time(sample.get("t_s")),
        )
    table.caption = f"{fmt_value(doc.get('samples'))} samples archived in {doc.get('archive')}"
    table.caption_justify = "left"
    return table


def history_tables(doc: dict[str, Any]) -> list[Table]:
    """Each channel's archived samples (time, source, value) or buckets (time, source, count,
    min, mean, max)."""
    bucketed = doc.get("bucket_s") is not None
    tables = []
    for ch in doc.get("channels") or []:
        unit = ch.get("unit") or ""
        u = f" ({unit})" if unit else ""
        title = f"{ch.get('channel')} history"
        if bucketed:
            title += f", {doc['bucket_s']:g} s buckets"
        table = Table(title=title, box=box.SIMPLE_HEAVY, show_edge=False, title_justify="left")
        table.add_column("time")
        table.add_column("source")
        times = ch.get("t_s") or []
        sources = ch.get("source") or []
        if bucketed:
            table.add_column("count", justify="right")
            for name in ("min", "mean", "max"):
                table.add_column(f"{name}{u}", justify="right")
            for i, t_s in enumerate(times):
                table.add_row(
                    fmt_time(t_s),
                    sources[i],
                    str(ch["count"][i]),
                    fmt_value(ch["min"][i]),
                    fmt_value(ch["mean"][i]),
                    fmt_value(ch["max"][i]),
                )
            table.caption = f"{len(times)} buckets of {sum(ch.get('count') or [])} samples"
        else:
            table.add_column(f"value{u}", justify="right")
            for t_s, source, value in zip(times, sources, ch.get("value") or [], strict=False):
                table.add_row(fmt_time(t_s), source, fmt_value(value))
            table.caption = f"{len(times)} samples"
        table.caption_justify = "left"
        tables.append(table)
    return tables


def events_table(doc: dict[str, Any], title: str | None = "events") -> Table:
    """Events, newest last, level coloured."""
    table = Table(title=title, box=box.SIMPLE_HEAVY, show_edge=False, title_justify="left")
    table.add_column("time")
    table.add_column("level")
    table.add_column("source")
    table.add_column("message")
    for event in doc.get("events") or []:
        level = str(event.get("level", ""))
        table.add_row(
            fmt_time(event.get("t_s")),
            Text(level, style=LEVEL_STYLE.get(level.lower(), "")),
            cell(event.get("source")),
            cell(event.get("message")),
        )
    if not doc.get("events"):
        table.caption = "no events"
    return table


def control_text(doc: dict[str, Any]) -> Text:
    """``nobody`` or ``alice@pc1 since 12:03:04 (lease until 12:04:04)``, then what the holder
    says it is doing (``; doing: campaign x: step 3/12 ... (2/12)``); "you" marked."""
    holder = doc.get("holder")
    if holder is None:
        return Text("nobody (any client may change the camera)", style="green")
    until = doc.get("expires_t_s")
    why = f"{doc.get('why')}, until {fmt_time(until)}" if until else str(doc.get("why"))
    mine = holder == doc.get("you")
    activity = doc.get("activity")
    doing = ""
    if activity:
        done, total = activity.get("done"), activity.get("total")
        steps = f" ({done if done is not None else '?'}/{total})" if total is not None else ""
        doing = f"; doing: {activity.get('text')}{steps}"
    return Text.assemble(
        (str(holder), "bold green" if mine else "bold yellow"),
        " (you)" if mine else "",
        f" since {fmt_time(doc.get('since_t_s'))} ({why}){doing}",
    )


def estop_text(latch: dict[str, Any]) -> Text:
    """``LATCHED since 12:03:04 by alice@pc1 (stopped stage, wheel); release: ...`` in red, or
    ``released ...`` / ``not latched``."""
    if latch.get("latched"):
        stopped = ", ".join(latch.get("stopped") or []) or "nothing"
        failed = "; ".join(latch.get("failed") or [])
        return Text(
            f"LATCHED since {fmt_time(latch.get('since_t_s'))} by {latch.get('by')} (stopped "
            f"{stopped}" + (f"; could not stop {failed}" if failed else "") + "): nothing "
            f"moves or acquires; {latch.get('how_to_release')}",
            style="bold red",
        )
    if latch.get("released_t_s") is not None:
        return Text(
            f"not latched (released at {fmt_time(latch.get('released_t_s'))} by "
            f"{latch.get('released_by')})",
            style="green",
        )
    return Text("not latched", style="green")
