"""The workload of ``camd soak`` (``camd.soak.command``): a daemon on a lossy simulated line, a
mixed stream of requests through ``CamdClient``, and the counts that say whether it held up.

``Soak.run()`` starts ``camd serve --sim`` (``DaemonProcess``, loopback, a 32-row hr400 window),
runs every workload kind once and then the mix for ``warmup_minutes`` as a warm-up, takes the
daemon's resources as the start, then runs kinds drawn from a seeded weighted mix until the time
is up, sampling the resources every
``sample_s``; the end sample follows the last item. Every HTTP request goes through one
``_CountingClient`` (the campaign's too), which counts answers by class. The kinds of item
themselves (their requests and checks) are ``camd.soak.kinds``.

Sources of the figures:

- commands: the soak's API requests (counted here), the command link's host counters and the
  device's (``GET /api/v1/link``, deltas over the run), and ``executed_twice`` from the
  simulated device itself (SIM_GET_INJECTED, firmware_models/fpga.py: an executed command
  frame equal to one of the last 32 executed);
- frames: each acquisition's host counters (the stream/stare answer, the scan's ``stream``, the
  ``stream`` metadata of a campaign's recordings) against the simulator's stream engine
  (``GET /api/v1/sim/stream``, deltas over the run);
- resources: ``/proc/PID/status`` (VmRSS, Threads) and ``/proc/PID/fd`` of the daemon (and of
  the simulator, for information).
"""

from __future__ import annotations

import collections
import contextlib
import os
import random
import statistics
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Generic, Protocol, TypeVar, cast

import httpx

from camd.bench.common import proc_status_int
from camd.cli._daemon_proc import DaemonProcess, write_sim_config
from camd.client import CamdClient, CamdError
from camd.soak.kinds import MISSING_KINDS, WINDOW_ROWS, Frames, WorkloadKinds

__all__ = [
    "KINDS",
    "SoakAborted",
    "SoakSettings",
    "build_inject",
    "proc_sample",
]

# Workload kinds, in warm-up order, and their weights in the random mix after it.
KINDS = ("ping", "telemetry", "registers", "stream", "stare", "scan", "campaign")
WEIGHTS = {
    "ping": 3, "telemetry": 3, "registers": 3, "stream": 2, "stare": 2, "scan": 2, "campaign": 1,
}  # fmt: skip
# The stream engine's counters of frames made but never delivered whole, by cause.
INJECTED_KINDS = ("dropped", "corrupted", "shortened", "stalls", "undelivered")
ERRORS_KEPT = 20
RSS_SAMPLES = 5  # RSS growth: median of the first 5 samples against that of the last 5


class SoakAborted(RuntimeError):
    """The soak could not go on (the daemon did not start or died); the message says why."""


def build_inject(ber: float, drop: float, frame_faults: float, extra: str = "") -> dict[str, float]:
    """The simulator's ``--inject`` keys: the line's ``ber`` and ``drop``; ``frame_faults``
    each for frame_drop, frame_corrupt and frame_short, a quarter of it for frame_stall (a
    stall also loses the frames made until the host clears the halt); then ``extra``
    (``key=value,...``) added or overriding."""
    keys: dict[str, float] = {"ber": ber, "drop": drop}
    if frame_faults > 0:
        keys.update(
            frame_drop=frame_faults,
            frame_corrupt=frame_faults,
            frame_short=frame_faults,
            frame_stall=frame_faults / 4,
        )
    for part in extra.split(","):
        part = part.strip()
        if not part:
            continue
        key, sep, value = part.partition("=")
        if not sep:
            raise ValueError(f"--inject: {part!r} is not key=value (e.g. garbage=0.001)")
        try:
            keys[key.strip()] = float(value)
        except ValueError:
            raise ValueError(f"--inject: {key.strip()}={value!r} is not a number") from None
    return {k: v for k, v in keys.items() if v != 0}


def write_hr400_config(work_dir: Path, seed: int) -> Path:
    """``work_dir/camd.toml``: the soaks' daemon, a simulated hr400 seeded with ``seed``."""
    return write_sim_config(work_dir, "hr400", seed=seed)


def inject_text(keys: dict[str, float]) -> str:
    """``key=value,...`` as ``--inject`` takes it."""
    return ",".join(f"{k}={v:g}" for k, v in keys.items())


def proc_sample(pid: int | None) -> dict[str, int] | None:
    """RSS (kB), open file descriptors and threads of process ``pid`` (Linux /proc), or None
    when it cannot be read (gone, not Linux)."""
    if pid is None:
        return None
    try:
        fds = len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return None
    rss_kb = proc_status_int(pid, "VmRSS")
    threads = proc_status_int(pid, "Threads")
    if rss_kb is None or threads is None:
        return None
    return {"rss_kb": rss_kb, "fds": fds, "threads": threads}


@dataclass
class SoakSettings:
    """What ``camd soak`` was asked for."""

    minutes: float
    seed: int
    inject: dict[str, float]
    work_dir: Path
    sample_s: float = 60.0
    timeout_s: float = 60.0
    warmup_minutes: float = 0.0


@dataclass
class _KindStats:
    runs: int = 0
    failed: int = 0
    seconds: float = 0.0


class _CountingClient(CamdClient):
    """``CamdClient`` counting every HTTP request it makes, by how it was answered."""

    def __init__(self, url: str, *, timeout_s: float, client: str) -> None:
        super().__init__(url, timeout_s=timeout_s, client=client, token="")
        self.counts: collections.Counter[str] = collections.Counter()
        self.codes: collections.Counter[str] = collections.Counter()  # error answers by code
        self.errors: list[str] = []

    def _request(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        self.counts["sent"] += 1
        try:
            response = super()._request(method, path, **kwargs)
        except CamdError as exc:
            status = exc.http_status
            key = "no_answer" if status is None else "5xx" if status >= 500 else "4xx"
            self.counts[key] += 1
            self.codes[exc.code] += 1
            self.note(f"{method} {path}: HTTP {status or '-'} {exc.code}: {exc.message}")
            raise
        self.counts["2xx"] += 1
        return response

    def note(self, text: str) -> None:
        """Keep the first ``ERRORS_KEPT`` failure texts."""
        if len(self.errors) < ERRORS_KEPT:
            self.errors.append(" ".join(text.split())[:400])


class _Seeded(Protocol):
    seed: int


SettingsT = TypeVar("SettingsT", bound=_Seeded)


class SoakRun(Generic[SettingsT]):
    """What both soaks share: their settings (``s``), a progress line now and then, a random
    generator seeded from the settings, their daemon and counting client, and how a run on the
    daemon starts and ends (``interrupted`` by Ctrl-C, or ``error`` set by a lost daemon or a
    refused set-up)."""

    def __init__(self, settings: SettingsT, progress: Callable[[str], None]) -> None:
        self.s = settings
        self.progress = progress
        self.rng = random.Random(settings.seed)
        self.daemon: DaemonProcess | None = None
        self.client: _CountingClient | None = None
        self.interrupted = False
        self.error: str | None = None

    def _on_daemon(
        self,
        daemon: DaemonProcess,
        body: Callable[[], None],
        *,
        then: Callable[[], None] = lambda: None,
        tidy: Callable[[], None] = lambda: None,
    ) -> None:
        """Start ``daemon`` (SoakAborted if it does not start) and run ``body`` on it: Ctrl-C,
        SoakAborted and an API error end the body, noted, and ``then`` runs; whatever happens,
        ``tidy`` runs, the client is closed and the daemon stopped."""
        from camd.cli._daemon_proc import DaemonStartError

        self.daemon = daemon
        try:
            daemon.start()
        except DaemonStartError as exc:
            raise SoakAborted(f"the daemon did not start: {exc}") from None
        try:
            try:
                body()
            except KeyboardInterrupt:
                self.interrupted = True
            except SoakAborted as exc:
                self.error = str(exc)
            except CamdError as exc:  # the set-up itself failed
                self.error = f"{exc.message} (API code {exc.code})"
            then()
        finally:
            tidy()
            if self.client is not None:
                self.client.close()
            daemon.stop()

    def _alive(self) -> None:
        """SoakAborted, with the daemon's exit status and log, if the daemon has exited."""
        assert self.daemon is not None
        if not self.daemon.running:
            raise SoakAborted(
                f"the daemon exited (status {self.daemon.stop()}) during the soak; its log is "
                f"{self.daemon.log_path}"
            )


class Soak(SoakRun[SoakSettings]):
    """One soak run (module docstring). ``progress`` gets a line of text now and then."""

    def __init__(self, settings: SoakSettings, progress: Callable[[str], None]) -> None:
        super().__init__(settings, progress)
        self.kinds: dict[str, _KindStats] = {k: _KindStats() for k in KINDS}
        self.frames = Frames()
        self.check_failures = 0
        self.recoveries: collections.Counter[str] = collections.Counter()
        self.items = 0
        self.samples: list[dict[str, Any]] = []
        self.t0 = 0.0
        self._kinds: WorkloadKinds | None = None  # once the client and the line period are known
        self.sim_pid: int | None = None
        self.link_before: dict[str, Any] = {}
        self.link_after: dict[str, Any] = {}
        self.sim_before: dict[str, int] = {}
        self.sim_after: dict[str, int] = {}
        self.line_period_s = 0.0
        self.started_s = 0.0
        self.warmup_s = 0.0

    # -- the run --------------------------------------------------------------------------------

    def run(self) -> dict[str, Any]:
        """Run the soak; the result document (``camd.soak.command`` prints it). SoakAborted if the
        daemon does not start; a daemon lost later ends the run early with ``error`` set."""
        data = self.s.work_dir / "daemon"
        config = write_hr400_config(self.s.work_dir, self.s.seed)
        daemon = DaemonProcess(
            data,
            inject=inject_text(self.s.inject),
            record_dirs=[self.s.work_dir],  # stares, scans and campaigns beside its data
            extra_args=["--config", str(config)],
            env={"CAMD_TOKEN": ""},
        )
        self._on_daemon(daemon, self._run_on_daemon, then=self._collect_end)
        return self.result()

    def _collect_end(self) -> None:
        """The end sample and the final counters, if the run did not get to take them."""
        if self.client is None or self.daemon is None or not self.daemon.running:
            return
        try:
            if self.t0 and not any(s["what"] == "end" for s in self.samples):
                self._sample("end")
            if not self.link_after:
                self.link_after = self._link()
            if not self.sim_after:
                self.sim_after = self._sim_stats()
        except CamdError as exc:
            self.error = self.error or f"the final counters could not be read: {exc.message}"

    def _run_on_daemon(self) -> None:
        assert self.daemon is not None
        self.client = client = _CountingClient(
            self.daemon.url, timeout_s=self.s.timeout_s, client="camd-soak"
        )
        status = client.wait_ready(60.0)
        self.sim_pid = (status.get("link") or {}).get("sim_pid")
        client.write_registers({"WIN_ROWS": WINDOW_ROWS})
        self.line_period_s = float(client.timing()["line_period_s"])
        self._kinds = WorkloadKinds(
            client, self.rng, self.s.work_dir, self.frames, self.line_period_s
        )
        self.link_before = self._link()
        self.sim_before = self._sim_stats()
        self.t0 = time.monotonic()
        self.progress(
            f"soak: daemon pid {self.daemon.pid} at {self.daemon.url}, simulator pid "
            f"{self.sim_pid}, line faults {inject_text(self.s.inject) or 'none'}; warm-up: one "
            f"of each kind ({', '.join(KINDS)}), then the mix for {self.s.warmup_minutes:g} min"
        )
        for kind in KINDS:
            self._item(kind)
        names = list(WEIGHTS)
        weights = [WEIGHTS[k] for k in names]
        # The daemon's RSS climbs for the first minutes of a mixed workload (the allocator's
        # arenas, HDF5's and numpy's caches, thread stacks touched for the first time) and then
        # levels off: measured 251 MB after one item of each kind, 396 MB at 5 min, 404 MB at
        # 40 min. Growth is measured from after that climb, or a leak could hide in it or a
        # plateau read as one.
        warmup_end = time.monotonic() + self.s.warmup_minutes * 60.0
        while time.monotonic() < warmup_end:
            self._item(self.rng.choices(names, weights)[0])
        self.warmup_s = time.monotonic() - self.t0
        self._sample("start")
        deadline = time.monotonic() + self.s.minutes * 60.0
        next_sample = time.monotonic() + self.s.sample_s
        while time.monotonic() < deadline:
            self._item(self.rng.choices(names, weights)[0])
            if time.monotonic() >= next_sample:
                self._sample("periodic")
                next_sample += self.s.sample_s
        self._collect_end()

    def _sim_stats(self) -> dict[str, int]:
        assert self.client is not None
        return dict(cast(Mapping[str, int], self.client.sim_stream_stats()))

    def _link(self) -> dict[str, Any]:
        assert self.client is not None
        return dict(self.client.link())

    def _item(self, kind: str) -> None:
        """Run one workload item of ``kind``; count it, never raise for its failure."""
        assert self.client is not None and self._kinds is not None
        stats = self.kinds[kind]
        stats.runs += 1
        self.items += 1
        started = time.monotonic()
        try:
            self._kinds.run(kind, self.items)
        except Exception as exc:  # CamdError, CheckFailed, or a bug: a failed item
            stats.failed += 1
            if not isinstance(exc, CamdError):  # the client noted those already
                self.check_failures += 1
                self.client.note(f"{kind}: {type(exc).__name__}: {exc}")
            self._alive()
            self._recover(str(exc))
        finally:
            stats.seconds += time.monotonic() - started

    def _recover(self, why: str) -> None:
        """After a failed item: nothing left streaming or scanning, control given back, and
        the sensor's LVDS link trained again if that is what failed (counted in
        ``recoveries``), so that one failure does not fail every acquisition after it."""
        assert self.client is not None
        undo: list[Callable[[], object]] = [
            self.client.stop_scan, self.client.stop_stream, self.client.release_control,
        ]  # fmt: skip
        if "LINK_UNTRAINED" in why:
            undo.append(self.client.train)
            self.recoveries["train"] += 1
        for action in undo:
            with contextlib.suppress(CamdError):
                action()

    # -- bookkeeping ----------------------------------------------------------------------------

    def _sample(self, what: str) -> None:
        assert self.daemon is not None
        doc: dict[str, Any] = {
            "what": what,
            "t_min": round((time.monotonic() - self.t0) / 60.0, 3),
            "items": self.items,
            "daemon": proc_sample(self.daemon.pid),
            "simulator": proc_sample(self.sim_pid),
        }
        self.samples.append(doc)
        self.progress(self._progress_line(doc))

    def _progress_line(self, sample: dict[str, Any]) -> str:
        assert self.client is not None
        d = sample["daemon"] or {}
        f = self.frames
        missing = sum(f.host[k] for k in MISSING_KINDS)
        failed = self._failed_requests() + self.check_failures
        return (
            f"[{sample['t_min']:6.1f} min] {sample['what']:8} items {self.items:5d}, "
            f"requests {self.client.counts['sent']:6d}, failed {failed}, frames "
            f"{f.delivered} delivered {missing} missing; daemon RSS "
            f"{d.get('rss_kb', 0) / 1024:.1f} MB, fds {d.get('fds', '?')}, threads "
            f"{d.get('threads', '?')}"
        )

    def _failed_requests(self) -> int:
        assert self.client is not None
        counts = self.client.counts
        return counts["4xx"] + counts["5xx"] + counts["no_answer"]

    # -- the result -----------------------------------------------------------------------------

    def result(self) -> dict[str, Any]:
        """The result document (docs/cli.md, ``camd soak``)."""
        client, daemon = self.client, self.daemon
        counts = client.counts if client is not None else collections.Counter[str]()
        host = _delta(self.link_before.get("host"), self.link_after.get("host"))
        device_b = self.link_before.get("device") or {}
        device_a = self.link_after.get("device") or {}
        device = _delta(
            {k: v for k, v in device_b.items() if isinstance(v, int)},
            {k: v for k, v in device_a.items() if isinstance(v, int)},
        )
        # Since the simulator started: the set-up and the warm-up count too.
        twice = (device_a.get("injected") or {}).get("executed_twice")
        executed_twice = int(twice) if twice is not None else None
        injected = _delta(self.sim_before, self.sim_after)
        f = self.frames
        missing = sum(f.host[k] for k in MISSING_KINDS)
        injected_total = sum(injected.get(k, 0) for k in INJECTED_KINDS) if injected else None
        unanswered = host.get("failed", 0) if host else 0
        failed_requests = counts["4xx"] + counts["5xx"] + counts["no_answer"]
        failed_total = failed_requests + self.check_failures + unanswered
        resources = self._resources()
        start, end = resources["start"], resources["end"]
        growth = resources["growth_pct"]
        frames_equal = injected_total is not None and missing == injected_total
        verdict = {
            "failed_commands_0": failed_total == 0 and bool(host),
            "executed_twice_0": executed_twice == 0,
            "lost_equals_injected": frames_equal,
            "rss_growth_below_5pct": growth.get("rss_kb") is not None and growth["rss_kb"] < 5.0,
            "fds_flat": bool(start and end and end["fds"] <= start["fds"]),
            "threads_flat": bool(start and end and end["threads"] <= start["threads"]),
        }
        return {
            "minutes": self.s.minutes,
            "seconds": round(time.monotonic() - self.t0, 1) if self.t0 else 0.0,
            "warmup_minutes": self.s.warmup_minutes,
            "warmup_s": round(self.warmup_s, 1),
            "seed": self.s.seed,
            "inject": inject_text(self.s.inject),
            "interrupted": self.interrupted,
            "error": self.error,
            "daemon": {
                "url": daemon.url if daemon is not None and daemon.exit_code is None else None,
                "pid": daemon.pid if daemon is not None else None,
                "sim_pid": self.sim_pid,
                "log": str(daemon.log_path) if daemon is not None else None,
                "exit_code": daemon.exit_code if daemon is not None else None,
            },
            "workload": {
                "items": self.items,
                "kinds": {
                    k: {"runs": v.runs, "failed": v.failed, "seconds": round(v.seconds, 2)}
                    for k, v in self.kinds.items()
                },
            },
            "commands": {
                "sent": counts["sent"],
                "answered": {k: counts[k] for k in ("2xx", "4xx", "5xx", "no_answer")},
                "failed": failed_total,
                "failed_requests": failed_requests,
                "failed_checks": self.check_failures,
                "device_unanswered": unanswered,
                "executed_twice": executed_twice,
                "recoveries": dict(self.recoveries),
                "device_commands": (host.get("acked", 0) + host.get("nacked", 0) + unanswered)
                if host
                else None,
                "link_host": host,
                "link_device": device,
                "errors": list(client.errors) if client is not None else [],
            },
            "frames": {
                "acquisitions": f.acquisitions,
                "requested": f.produced_requested,
                "delivered": f.delivered,
                "host": {k: f.host[k] for k in (*MISSING_KINDS, "stalls", "out_of_order")},
                "lost": missing,
                "injected": injected_total,
                "device": injected,
                "equal": frames_equal,
            },
            "resources": resources,
            "verdict": verdict,
        }

    def _resources(self) -> dict[str, Any]:
        start = next((s["daemon"] for s in self.samples if s["what"] == "start"), None)
        end = next((s["daemon"] for s in self.samples if s["what"] == "end"), None)
        # RSS at one instant swings by tens of MB with the buffers of whatever acquisition is
        # live (a scan's batches are 64 MB): compare the medians of the first and the last
        # RSS_SAMPLES samples instead of two instants. Descriptors and threads are exact.
        series = [s["daemon"] for s in self.samples if s["daemon"]]
        k = max(1, min(RSS_SAMPLES, len(series) // 2))
        rss_start = statistics.median(d["rss_kb"] for d in series[:k]) if series else None
        rss_end = statistics.median(d["rss_kb"] for d in series[-k:]) if series else None
        growth: dict[str, float | None] = {}
        if rss_start and rss_end:
            growth["rss_kb"] = round(100.0 * (rss_end - rss_start) / rss_start, 2)
        else:
            growth["rss_kb"] = None
        for key in ("fds", "threads"):
            if start and end and start[key]:
                growth[key] = round(100.0 * (end[key] - start[key]) / start[key], 2)
            else:
                growth[key] = None
        return {
            "start": start, "end": end, "rss_median_kb": {"start": rss_start, "end": rss_end},
            "rss_samples": k, "growth_pct": growth, "series": self.samples,
        }  # fmt: skip


def _delta(before: dict[str, Any] | None, after: dict[str, Any] | None) -> dict[str, int]:
    """after - before of the integer counters both have ({} if either is missing)."""
    if not before or not after:
        return {}
    return {
        k: int(after[k]) - int(before[k])
        for k in after
        if k in before and isinstance(after[k], int) and isinstance(before[k], int)
    }
