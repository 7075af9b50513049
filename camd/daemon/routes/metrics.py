"""Prometheus metrics (docs/api.md, ``GET /metrics``): state, link counters, stream and scan
gauges, telemetry and its limit levels, read from the session at scrape time (no device
traffic)."""

from __future__ import annotations

from collections.abc import Iterable

from fastapi import APIRouter, Response
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector, CollectorRegistry

import camd
from camd.daemon.routes.deps import Session
from camd.daemon.session import DeviceSession
from camd.daemon.state import State
from camd.daemon.telemetry import Level, classify

router = APIRouter(tags=["status"])


class _SessionCollector(Collector):
    """Prometheus metrics read from the session at scrape time (no device traffic)."""

    def __init__(self, session: DeviceSession) -> None:
        self.session = session

    def collect(self) -> Iterable[Metric]:
        """The metric families, built fresh at each scrape."""
        session = self.session
        state = GaugeMetricFamily(
            "camd_state", "1 for the daemon's current state, 0 for the others", labels=["state"]
        )
        current = session.state
        for s in State:
            state.add_metric([s.value], 1.0 if s == current else 0.0)
        yield state
        link = session.link
        yield GaugeMetricFamily(
            "camd_link_connected",
            "1 while the command link's port is open",
            value=1.0 if link is not None and link.connected else 0.0,
        )
        for name, count in session.link_commands.host_counters().items():
            yield CounterMetricFamily(
                f"camd_link_{name}", f"command link host counter: {name}", value=count
            )
        yield GaugeMetricFamily(
            "camd_stream_active", "1 while frames stream", value=float(session.stream.streaming)
        )
        mismatch = GaugeMetricFamily(
            "camd_scan_m_dv_over_v",
            "current or last scan: M |dV/V| (pixels of smear) of the last batch, max and RMS",
            labels=["stat"],
        )
        for stat, number in session.scan.mismatch_gauges().items():
            mismatch.add_metric([stat], number)
        yield mismatch
        for name, number in session.stream.stats().model_dump().items():
            # Per stream (reset when one starts), so gauges rather than counters.
            yield GaugeMetricFamily(
                f"camd_stream_{name}", f"frame stream ingest, current or last stream: {name}",
                value=float(number),
            )  # fmt: skip
        values = GaugeMetricFamily(
            "camd_telemetry_value",
            "latest housekeeping value per channel, in the channel's unit",
            labels=["channel", "unit"],
        )
        levels = GaugeMetricFamily(
            "camd_telemetry_limit_level",
            "limit level of the latest value: 0 ok, 1 yellow, 2 red",
            labels=["channel"],
        )
        level_number = {Level.OK: 0.0, Level.YELLOW: 1.0, Level.RED: 2.0}
        for channel, value in sorted(session.telemetry.latest_values().items()):
            values.add_metric([channel, session.telemetry.channels.get(channel, "")], value)
            limits = session.config.telemetry.limits.get(channel)
            if limits is not None:
                levels.add_metric([channel], level_number[classify(value, limits)])
        yield values
        yield levels
        archive = session.telemetry.archive
        if archive is not None:
            yield GaugeMetricFamily(
                "camd_telemetry_archived_samples",
                "samples in the SQLite archive",
                value=archive.count(),
            )
        yield GaugeMetricFamily(
            "camd_uptime_seconds", "time since the daemon started", value=session.uptime_s
        )
        info = GaugeMetricFamily("camd_info", "daemon version", labels=["version"])
        info.add_metric([camd.__version__], 1.0)
        yield info


@router.get("/metrics", response_class=Response)
def get_metrics(session: Session) -> Response:
    """Prometheus text exposition: link counters, telemetry, state."""
    registry = CollectorRegistry(auto_describe=False)  # per scrape: it only holds the collector
    registry.register(_SessionCollector(session))
    return Response(generate_latest(registry), media_type=CONTENT_TYPE_LATEST)
