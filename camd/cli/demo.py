"""``camd demo``: the main job in one command, on the simulated camera.

Starts ``camd serve --sim`` on a lossy line (bit errors and dropped frames), then, through
``CamdClient`` exactly as any script would: shows the status, pings the device, compares the
host's and the device's link counters (every command executed at most once although frames were
lost and retried), shows telemetry being archived, switches area -> tdi -> area, lists the
events, then runs short forms of two shipped test campaigns (``tdi_snr_stages``,
``mtf_mismatch``), each on a simulated camera of its own profile, and prints where their reports
are; stops the daemon and writes everything to ``OUT/demo-summary.json``. As soon as the daemon
runs it prints the address of its live view (``http://HOST:PORT/live``), where the demo's streams
and scans can be watched.

``--keep``: after the campaigns (which run beside the daemon, on their own simulated cameras), the
daemon is not stopped: it streams a moving bar target, prints the live view's address again and
waits for Ctrl-C (or SIGTERM), then stops the stream and the daemon and ends as usual.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import threading
import time
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import quote

from camd.cli.camctl_args import int_range

if TYPE_CHECKING:
    from rich.console import Console

    from camd.cli._daemon_proc import DaemonProcess
    from camd.client import CamdClient

DEFAULT_OUT = "camd-demo"
DEFAULT_PINGS = 1000
# The demo's line: enough faults that retries happen in every run, few enough that none fails.
DEMO_INJECT = "ber=1e-4,drop=0.01,frame_drop=0.02,frame_corrupt=0.01,frame_short=0.01"
DEMO_FRAMES = 200
DEMO_STARE_FRAMES = 10
DEMO_SCAN_STAGES = (1, 8, 32)
DEMO_SCAN_LINES = 400  # complete lines asked for: ten periods of the bar target
DEMO_SCAN_SCENE = "bars:lux=20"
# Short (--quick) runs of two shipped campaigns, each on its own simulated camera of the
# campaign's profile (docs/campaigns.md), with their reports.
DEMO_CAMPAIGNS = ("tdi_snr_stages", "mtf_mismatch")
TELEMETRY_WAIT_S = 3.0
TELEMETRY_GRACE_S = 5.0  # extra wait if no new sample arrived in TELEMETRY_WAIT_S
# Commands that may fall between the two link snapshots on one side and not the other: the
# snapshot's own GET_LINK_STATS / SIM_GET_INJECTED and a housekeeping poll in flight, at each
# of the two snapshots. A command executed twice per lost acknowledge would show as a
# difference of about `replayed`, far above this.
AT_MOST_ONCE_SLACK = 4
LIVE_PAGE = "/live"
# --keep: what the live view shows until Ctrl-C. YE23's window at 20 frames a second (the live
# view's own rate: a longer exposure sets the frame period, max(k, n + 1) lines), the bar target
# moving one row a frame with the ideal stage; lux=4 fills about half the 12-bit range at the
# 50 ms exposure.
KEEP_FRAME_PERIOD_S = 0.05
KEEP_WINDOW = {"WIN_START": 757, "WIN_ROWS": 534}
KEEP_SCENE = "bars:lux=4"


def add_parser(sub: Any) -> None:
    """Register ``camd demo`` (called by camd.cli.camd_main)."""
    p: argparse.ArgumentParser = sub.add_parser(
        "demo",
        help="run the main job on the simulated camera and write a summary",
        description="Start the daemon on the simulated camera with a lossy line "
        f"(--inject {DEMO_INJECT}), ping it, compare link counters, show telemetry, switch "
        "modes, list events, stop it, and write OUT/demo-summary.json.",
    )
    p.add_argument(
        "--out",
        default=DEFAULT_OUT,
        metavar="DIR",
        help=f"directory for the summary, the daemon's data and its log (default ./{DEFAULT_OUT})",
    )
    p.add_argument(
        "--pings",
        type=int_range(1, 100_000),
        default=DEFAULT_PINGS,
        metavar="N",
        help=f"number of pings, 1..100000 (default {DEFAULT_PINGS})",
    )
    p.add_argument(
        "--keep",
        action="store_true",
        help="after the steps, leave the daemon and the simulated camera running (streaming a "
        "moving target to the live view) until Ctrl-C",
    )
    p.add_argument(
        "--no-campaigns",
        action="store_true",
        help="skip step 10, the two short campaign runs (about 20 s)",
    )


class DemoFailed(Exception):
    """A demo check failed; the message says which and where to look."""


def run(args: argparse.Namespace) -> int:
    """Run the demo; 0 if every step passed, 1 otherwise (the reason on stderr)."""
    return run_demo(args.out, args.pings, keep=args.keep, campaigns=not args.no_campaigns)


def live_page_url(daemon_url: str, token: str | None = None) -> str:
    """The address of a daemon's live view, with ``?token=`` when it has a token."""
    query = f"?token={quote(token, safe='')}" if token else ""
    return f"{daemon_url.rstrip('/')}{LIVE_PAGE}{query}"


def run_demo(
    out: str | os.PathLike[str],
    pings: int = DEFAULT_PINGS,
    *,
    keep: bool = False,
    campaigns: bool = True,
) -> int:
    """Run the whole demo with its output in ``out``; returns the exit status. ``keep``: leave
    the daemon running until SIGINT/SIGTERM (module docstring); ``campaigns``: run step 10."""
    # Imported here, not at the top: camd_main imports this module to build its parser for
    # every subcommand, and `camd serve` should not pay for rich and the client.
    from rich.console import Console

    import camd
    from camd.cli._daemon_proc import DaemonProcess, DaemonStartError
    from camd.client import CamdClient, CamdError

    out_dir = Path(out)
    summary_path = out_dir / "demo-summary.json"
    # Not a terminal (CI, a pipe): a fixed, wide page instead of rich's 80 columns.
    console = Console(highlight=False, width=None if sys.stdout.isatty() else 120)
    started = time.monotonic()
    summary: dict[str, Any] = {
        "ok": False,
        "error": None,
        "camd_version": camd.__version__,
        "out_dir": str(out_dir.resolve()),
        "pings_requested": pings,
        "inject": DEMO_INJECT,
        "daemon": {},
        "live_url": None,
        "campaigns": [],
    }
    daemon = DaemonProcess(out_dir, inject=DEMO_INJECT)
    error: str | None = None
    interrupted = False

    console.rule("[bold]camd demo[/bold]: simulated camera, lossy RS-422 line")
    try:
        with console.status(f"starting camd serve --sim --inject {DEMO_INJECT} ..."):
            daemon.start()
        summary["daemon"] = {"url": daemon.url, "pid": daemon.pid, "log": str(daemon.log_path)}
        # The daemon takes $CAMD_TOKEN as its token (the shipped config has none).
        live_url = live_page_url(daemon.url, os.environ.get("CAMD_TOKEN"))
        summary["live_url"] = live_url
        console.print(
            f"daemon pid {daemon.pid} serving {daemon.url}, data in {out_dir}, "
            f"line faults {DEMO_INJECT}"
        )
        console.print(
            f"live view: {live_url} (open it in a browser to watch the streams and scans below)",
            soft_wrap=True,
        )
        with CamdClient(daemon.url) as client:
            _Demo(console, client, summary, pings, campaigns=campaigns).run()
            if keep:
                _keep(console, client, daemon, summary)
    except DaemonStartError as exc:
        error = f"the daemon did not start: {exc}"
    except CamdError as exc:
        error = f"{exc.message} (API code {exc.code}); the daemon's log is {daemon.log_path}"
    except DemoFailed as exc:
        error = str(exc)
    except OSError as exc:
        error = f"cannot use {out_dir} ({exc}); choose another directory with --out"
    except KeyboardInterrupt:
        error = "interrupted"
        interrupted = True
    finally:
        exit_code = daemon.stop()

    if exit_code is not None:
        summary["daemon"].update(exit_code=exit_code, killed=daemon.killed)
        # Ending by SIGTERM's default action (-15) is stopping as asked, as systemd sees it too;
        # needing SIGKILL after the stop timeout is not.
        if error is None and (exit_code not in (0, -signal.SIGTERM) or daemon.killed):
            how = " (it ignored SIGTERM and was killed)" if daemon.killed else ""
            error = (
                f"the daemon did not stop cleanly: exit status {exit_code}{how}; "
                f"see {daemon.log_path}"
            )
        elif error is None:
            how = "on SIGTERM" if exit_code else "with exit status 0"
            console.print(f"daemon stopped cleanly {how}")
    summary["ok"] = error is None
    summary["error"] = error
    summary["duration_s"] = round(time.monotonic() - started, 3)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        summary_path.write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    except OSError as exc:
        error = error or f"cannot write {summary_path} ({exc}); choose another directory with --out"

    if error is not None:
        print(f"camd demo: error: {error}", file=sys.stderr)
        return 130 if interrupted else 1
    ping = summary["ping"]
    check = summary["at_most_once"]
    tel = summary["telemetry"]
    stream = summary["stream"]["tdi"]
    rec = summary["stream"]["recording"]
    scan_stages = "/".join(str(r["stages"]) for r in summary["scans"])
    scan_snr = "/".join(f"{r['snr_db']:.1f}" for r in summary["scans"])
    reports = (
        "campaign reports " + ", ".join(c["report"] for c in summary["campaigns"])
        if campaigns
        else "campaigns skipped (--no-campaigns)"
    )
    # Plain print, never wrapped: scripts and the README quote this line.
    print(
        f"demo OK: {ping['count']} pings, {ping['retries']} retries, {ping['failed']} failed, "
        f"rtt p50/p99 {_ms(ping['rtt_ms']['p50'])}/{_ms(ping['rtt_ms']['p99'])} ms, "
        f"at most once: {check['device_executed']} executed for {check['host_answered']} "
        f"answered ({check['device_replayed']} replayed), "
        f"{tel['samples_after']} telemetry samples archived, "
        f"{stream['frames']} of {DEMO_FRAMES} frames delivered ({stream['lost']} lost, "
        f"{stream['corrupt'] + stream['short']} damaged, all as injected), "
        f"{rec['frames']} recorded and verified, TDI scans at M = {scan_stages} with SNR "
        f"{scan_snr} dB; {reports}; summary in {summary_path}",
        flush=True,
    )
    return 0


class _Demo:
    """The demo's steps against a running daemon; each records its results in ``summary``."""

    def __init__(
        self,
        console: Console,
        client: CamdClient,
        summary: dict[str, Any],
        pings: int,
        *,
        campaigns: bool = True,
    ):
        self.console = console
        self.client = client
        self.summary = summary
        self.pings = pings
        self.with_campaigns = campaigns

    def run(self) -> None:
        self.status()
        self.ping_and_link()
        self.telemetry()
        self.modes()
        self.sensor()
        self.stream()
        self.scan()
        self.events()
        if self.with_campaigns:
            self.campaigns()
        else:
            self.step("10. test campaigns: skipped (--no-campaigns)")

    def step(self, title: str) -> None:
        self.console.print()
        self.console.rule(f"[bold]{title}", align="left")

    # -- steps ------------------------------------------------------------------------------------

    def status(self) -> None:
        from rich.table import Table

        from camd.cli.camctl_format import fmt_firmware, fmt_value, state_text

        self.step("1. status")
        doc = _plain(self.client.wait_ready(10.0))
        self.summary["status"] = doc
        device = doc.get("device") or {}
        daemon = doc.get("daemon") or {}
        table = Table(show_header=True, box=None, pad_edge=False)
        for name in ("state", "mode", "firmware", "device uptime", "daemon", "link"):
            table.add_column(name)
        link = doc.get("link") or {}
        table.add_row(
            state_text(doc.get("state")),
            fmt_value(doc.get("mode")),
            fmt_firmware(device.get("fw_version")),
            _seconds(device.get("uptime_s")),
            f"{daemon.get('version', '?')}, up {_seconds(daemon.get('uptime_s'))}",
            f"{link.get('port', '?')} ({'connected' if link.get('connected') else 'not connected'})",
        )
        self.console.print(table)
        if doc.get("state") != "idle":
            raise DemoFailed(
                f"the daemon is {doc.get('state')!r}, not 'idle' ({doc.get('reason')}); "
                f"see its log {self.summary['daemon'].get('log')}"
            )

    def ping_and_link(self) -> None:
        from camd.cli.camctl_format import link_table, ping_table

        self.step(f"2. {self.pings} pings over the lossy line")
        before = _plain(self.client.link())
        with self.console.status(f"pinging the device {self.pings} times ..."):
            ping = _plain(self.client.ping(count=self.pings))
        after = _plain(self.client.link())
        self.summary["ping"] = ping
        self.summary["link"] = {"before": before, "after": after}
        self.console.print(ping_table(ping, title=None))
        for reason in ping.get("errors") or []:
            self.console.print(f"  [red]error:[/red] {reason}")
        if ping.get("failed") or ping.get("ok") != ping.get("count"):
            raise DemoFailed(
                f"{ping.get('failed')} of {ping.get('count')} pings failed "
                f"({'; '.join(ping.get('errors') or []) or 'no reason given'}); "
                "the link should recover every frame lost on this line"
            )

        self.step("3. link counters: host vs device")
        self.console.print(link_table(after, title=None))
        check = at_most_once(before, after)
        self.summary["at_most_once"] = check
        self.console.print(
            f"during the pings: host sent {check['host_sent']} frames with "
            f"{check['host_retries']} retries ({check['host_timeouts']} timeouts) and got "
            f"{check['host_answered']} answers; the device executed {check['device_executed']} "
            f"commands and answered {check['device_replayed']} retries from its record "
            "instead of executing them again."
        )
        if check["held"]:
            self.console.print(
                f"[green]at-most-once holds[/green]: executed - answered = "
                f"{check['difference']} (commands straddling the two snapshots, "
                f"|difference| <= {check['tolerance']})"
            )
        else:
            raise DemoFailed(
                f"at-most-once violated: the device executed {check['device_executed']} "
                f"commands for {check['host_answered']} answered by the host "
                f"(difference {check['difference']}, tolerance {check['tolerance']}); "
                "a retried command was executed again"
            )

    def telemetry(self) -> None:
        from camd.cli.camctl_format import telemetry_table

        self.step("4. telemetry")
        first = _plain(self.client.telemetry())
        with self.console.status(f"collecting housekeeping for {TELEMETRY_WAIT_S:g} s ..."):
            time.sleep(TELEMETRY_WAIT_S)
            last = _plain(self.client.telemetry())
            deadline = time.monotonic() + TELEMETRY_GRACE_S
            while last.get("samples", 0) <= first.get("samples", 0) and (
                time.monotonic() < deadline
            ):
                time.sleep(0.25)
                last = _plain(self.client.telemetry())
        self.console.print(telemetry_table(last, title=None))
        archive = str(last.get("archive"))
        record: dict[str, Any] = {
            "first": first,
            "last": last,
            "samples_before": first.get("samples"),
            "samples_after": last.get("samples"),
            "archive": archive,
            "archive_exists": Path(archive).exists(),
        }
        self.summary["telemetry"] = record
        latest = last.get("latest") or {}
        if not latest:
            raise DemoFailed(
                "the daemon reports no telemetry; housekeeping should arrive every second or so"
            )
        channel = "fpga_temp_degc" if "fpga_temp_degc" in latest else next(iter(latest))
        (history,) = self.client.history(channel)["channels"]
        record["history"] = {
            "channel": channel,
            "unit": history["unit"],
            "samples": len(history["value"]),
        }
        self.console.print(
            f"samples archived: {record['samples_before']} -> {record['samples_after']} in "
            f"{TELEMETRY_WAIT_S:g} s; archive {archive} "
            f"({'exists' if record['archive_exists'] else '[red]missing[/red]'}); "
            f"{record['history']['samples']} samples of {channel} read back from it"
        )
        if not last.get("samples", 0) > first.get("samples", 0):
            raise DemoFailed(
                f"no telemetry sample was archived in {TELEMETRY_WAIT_S + TELEMETRY_GRACE_S:g} s "
                f"(count stayed at {last.get('samples')}); check the housekeeping poll"
            )
        if not record["archive_exists"]:
            raise DemoFailed(f"the telemetry archive {archive} does not exist")

    def modes(self) -> None:
        from rich.table import Table

        from camd.cli.camctl_format import fmt_value, state_text

        self.step("5. imaging mode: area -> tdi -> area")
        table = Table(box=None, pad_edge=False)
        for name in ("step", "state", "mode", "device mode"):
            table.add_column(name)
        steps: list[dict[str, Any]] = []
        initial = _plain(self.client.status())
        steps.append({"requested": None, "status": initial})
        for mode in ("tdi", "area"):
            answer = _plain(self.client.set_mode(mode))
            status = _plain(self.client.status())
            steps.append({"requested": mode, "answer": answer, "status": status})
        for entry in steps:
            status = entry["status"]
            device = status.get("device") or {}
            table.add_row(
                "initial" if entry["requested"] is None else f"mode {entry['requested']}",
                state_text(status.get("state")),
                fmt_value(status.get("mode")),
                fmt_value(device.get("mode")),
            )
        self.console.print(table)
        self.summary["modes"] = steps
        for entry in steps[1:]:
            if entry["status"].get("mode") != entry["requested"]:
                raise DemoFailed(
                    f"after `mode {entry['requested']}` the status says mode "
                    f"{entry['status'].get('mode')!r}"
                )

    def sensor(self) -> None:
        from camd.cli.camctl_sensor import register_table, render_timing, render_train

        self.step("6. sensor: LVDS training, registers over SPI, timing")
        train = _plain(self.client.train())
        render_train(self.console, train, argparse.Namespace())
        window = {"WIN_START": 757, "WIN_ROWS": 534, "EXPOSURE": 2}  # YE23's mission window
        written = _plain(self.client.write_registers(dict(window)))
        self.console.print(register_table("written and verified", written["written"]))
        timing = _plain(self.client.timing())
        render_timing(self.console, timing, argparse.Namespace())
        self.summary["sensor"] = {"train": train, "written": written, "timing": timing}
        if not train.get("trained"):
            raise DemoFailed(f"LVDS training did not lock: {train}")
        expected_frame_s = (534 + 2 + 1) * timing["line_period_s"]  # (n + k + 1) T_line
        if abs(timing["frame_time_s"] - expected_frame_s) > 1e-12:
            raise DemoFailed(f"frame time {timing['frame_time_s']} != (n+k+1) T_line")

    def stream(self) -> None:
        from camd.cli.camctl_stream import flat, render_stream
        from camd.store import read_recording

        self.step(
            f"7. frame stream over USB bulk (pyusb), {DEMO_FRAMES} TDI frames of a bar target"
        )
        self.client.set_scene("bars:lux=20")
        before = _plain(self.client.sim_stream_stats())
        doc = flat(self.client.acquire(DEMO_FRAMES, mode="tdi", stages=32))
        after = _plain(self.client.sim_stream_stats())
        render_stream(self.console, doc, argparse.Namespace())
        kinds = ("dropped", "corrupted", "shortened", "stalls", "undelivered")
        injected = {k: after[k] - before[k] for k in kinds}
        self.console.print(
            f"the simulator dropped {injected['dropped']}, corrupted {injected['corrupted']} and "
            f"cut short {injected['shortened']} frames on purpose ({DEMO_INJECT})"
        )
        out = Path(self.summary["out_dir"]) / "stare.h5"
        out.unlink(missing_ok=True)
        stare = flat(self.client.acquire(DEMO_STARE_FRAMES, mode="area", record=str(out)))
        recording = read_recording(out)
        mismatches = recording.crc_mismatches()
        self.console.print(
            f"stare: {stare['frames']} area frames recorded to {out} "
            f"({recording.frames.shape[1]} x {recording.frames.shape[2]}); read back: "
            f"{len(recording.frames)} frames, {len(mismatches)} differing from the device's CRC"
        )
        self.summary["stream"] = {
            "tdi": doc, "injected": injected, "stare": stare,
            "recording": {"path": str(out), "frames": len(recording.frames),
                          "crc_mismatches": len(mismatches)},
        }  # fmt: skip
        # Never received: dropped, lost in a stall, or made while the endpoint was halted.
        missing = injected["dropped"] + injected["stalls"] + injected["undelivered"]
        if doc["lost"] != missing:
            raise DemoFailed(
                f"the daemon counted {doc['lost']} lost frames, the simulator lost {missing}"
            )
        if doc["corrupt"] + doc["short"] != injected["corrupted"] + injected["shortened"]:
            raise DemoFailed("damaged frames counted by the daemon differ from those injected")
        if doc["frames"] + doc["lost"] + doc["corrupt"] + doc["short"] != DEMO_FRAMES:
            raise DemoFailed(f"{DEMO_FRAMES} frames sent but the counts do not add up: {doc}")
        if mismatches or len(recording.frames) != stare["frames"]:
            raise DemoFailed(f"the recording {out} does not read back as streamed")

    def scan(self) -> None:
        from rich.table import Table

        from camd.analysis.tdi_snr import (
            QUANTISATION_SIGMA_DN,
            SnrMeasurement,
            db,
            periodic_snr,
            snr_gain_sqrt_m,
            snr_gain_tao12,
        )
        from camd.sensor.profile import load_profile
        from camd.store.tdi_recording import read_tdi_scan

        stages_list = ", ".join(str(m) for m in DEMO_SCAN_STAGES)
        self.step(f"8. push-broom scans with host TDI at M = {stages_list} of a bar target")
        rows = max(DEMO_SCAN_STAGES)
        timing = self.client.timing()
        period_s = rows * float(timing["line_period_s"])
        profile = load_profile(str(timing["sensor"]))
        scene_period = 40  # rows: the bar target's along-track period (docs/simulator.md)
        out_dir = Path(self.summary["out_dir"])
        results: list[tuple[int, dict[str, Any], SnrMeasurement]] = []
        for stages in DEMO_SCAN_STAGES:
            out = out_dir / f"scan-m{stages}.h5"
            out.unlink(missing_ok=True)
            out.with_suffix(".png").unlink(missing_ok=True)
            # An ideal stage: this step measures the SNR of TDI; the motion step drives the
            # stepper (a 32-row window's line period needs 167 mm/s, above the rail's limit).
            self.client.start_scan(
                stages, DEMO_SCAN_LINES, out=str(out), scene=DEMO_SCAN_SCENE,
                line_period_s=period_s, drive_stage=False,
            )  # fmt: skip
            doc = _plain(self.client.wait_scan(timeout_s=120))
            scan = read_tdi_scan(out)
            keep = scan.complete
            black = stages * profile.black_level_for(timing.get("offset"))
            measured = periodic_snr(
                scan.lines[keep], scan.line_index[keep], period=scene_period, black_dn=black
            )
            results.append((stages, doc, measured))
        first = results[0][2]
        sigma_cmos = math.sqrt(max(first.noise_dn**2 - QUANTISATION_SIGMA_DN**2, 0.0))
        table = Table(title=None, show_edge=False)
        for name in ("M", "lines", "complete", "lost", "signal DN", "noise DN", "SNR dB",
                     "sqrt(M) model dB", "TAO12 model dB", "file"):  # fmt: skip
            table.add_column(name, justify="left" if name == "file" else "right")
        rows_out = []
        for m, doc, snr in results:
            sqrt_db = first.snr_db + db(snr_gain_sqrt_m(m))
            tao_db = first.snr_db + db(snr_gain_tao12(m, QUANTISATION_SIGMA_DN, sigma_cmos))
            table.add_row(
                str(m), str(doc["lines"]), str(doc["complete_lines"]), str(doc["lost_frames"]),
                f"{snr.signal_dn:.1f}", f"{snr.noise_dn:.2f}", f"{snr.snr_db:.2f}",
                f"{sqrt_db:.2f}", f"{tao_db:.2f}", Path(doc["file"]).name,
            )  # fmt: skip
            rows_out.append({
                "stages": m, "file": doc["file"], "quicklook": doc["quicklook"],
                "lines": doc["lines"], "complete_lines": doc["complete_lines"],
                "lost_frames": doc["lost_frames"], "signal_dn": snr.signal_dn,
                "noise_dn": snr.noise_dn, "snr_db": snr.snr_db, "model_sqrt_m_db": sqrt_db,
                "model_tao12_db": tao_db,
            })  # fmt: skip
        self.console.print(table)
        self.console.print(
            f"SNR on the bright bars (temporal noise about the mean of lines {scene_period} "
            f"apart, complete lines only); models from M = 1: sqrt(M) (DONG16, and the "
            f"quadrature model) and TAO12 eq 28 with sigma_AD = 1/sqrt(12) DN, sigma_CMOS = "
            f"{sigma_cmos:.2f} DN. Lines lost to the injected frame faults are flagged "
            f"incomplete, never mis-summed. Quicklooks: scan-m*.png in {out_dir}"
        )
        self.summary["scans"] = rows_out
        for row in rows_out:
            if row["complete_lines"] < DEMO_SCAN_LINES // 4:
                raise DemoFailed(f"scan at M = {row['stages']} kept too few complete lines: {row}")

    def events(self) -> None:
        from camd.cli.camctl_format import events_table

        self.step("9. recent events")
        doc = _plain(self.client.events(limit=10))
        self.summary["events"] = doc.get("events", [])
        self.console.print(events_table(doc, title=None))

    def campaigns(self) -> None:
        import shutil

        from camd.campaign.loading import load_campaign
        from camd.campaign.spec import CampaignError
        from camd.cli.camctl_campaign import RichProgress, campaigns_dir, run_on_own_sim

        names = " and ".join(DEMO_CAMPAIGNS)
        self.step(f"10. test campaigns (short runs): {names}")
        out_dir = Path(self.summary["out_dir"]) / "campaigns"
        rows = []
        for name in DEMO_CAMPAIGNS:
            spec = load_campaign(campaigns_dir() / f"{name}.yaml")
            run_dir = out_dir / name
            shutil.rmtree(run_dir, ignore_errors=True)  # a fresh run, not a resume
            try:
                with RichProgress(self.console, name) as progress:
                    outcome = run_on_own_sim(spec, run_dir, quick=True, progress=progress)
            except CampaignError as exc:
                raise DemoFailed(f"campaign {name}: {exc}") from None
            failed = [c["id"] for c in outcome.doc["checks"] if not c["passed"]]
            self.console.print(
                f"{name} ({spec.profile}): {'PASSED' if outcome.passed else 'FAILED'}, "
                f"{len(outcome.doc['checks'])} checks; report {outcome.report_path}"
            )
            rows.append({"campaign": name, "profile": spec.profile, "passed": outcome.passed,
                         "failed_checks": failed, "report": str(outcome.report_path)})  # fmt: skip
        self.summary["campaigns"] = rows
        for row in rows:
            if not row["passed"]:
                raise DemoFailed(
                    f"campaign {row['campaign']} failed its checks {row['failed_checks']}; "
                    f"see {row['report']}"
                )


def _keep(
    console: Console, client: CamdClient, daemon: DaemonProcess, summary: dict[str, Any]
) -> None:
    """``--keep``: stream a moving target to the live view until SIGINT or SIGTERM, then stop
    the stream (the daemon is stopped by the caller, as without --keep)."""
    from camd.client import CamdError

    console.print()
    console.rule("[bold]kept running: the live view", align="left")
    timing = client.timing()
    exposure = max(1, round(KEEP_FRAME_PERIOD_S / float(timing["line_period_s"])) - 1)
    client.write_registers({**KEEP_WINDOW, "EXPOSURE": exposure})
    client.set_scene(KEEP_SCENE)
    client.set_stage(track=True)  # the scans left the ideal stage at their speed: track again
    doc = client.start_stream(0, mode="area")
    # The demo holds no lease: the page may take control. The stream itself holds it for the
    # demo's client while it runs (docs/api.md), so a page takes it over (and may stop it).
    client.release_control()
    record: dict[str, Any] = {
        "live_url": summary["live_url"],
        "scene": KEEP_SCENE,
        "stream": {k: doc[k] for k in ("mode", "rows", "cols", "frame_period_s")},
        "client": client.client,
        "signal": None,
        "stream_stopped": None,
    }
    summary["keep"] = record
    console.print(
        f"streaming {doc['rows']} x {doc['cols']} area frames of a moving bar target "
        f"({KEEP_SCENE}) at {1 / doc['frame_period_s']:.0f} frames/s, until stopped; the line "
        "still drops, corrupts and cuts short some frames on purpose. The stream is "
        f"{client.client}'s (this demo) while it runs: the page watches without control, and "
        "taking control there takes the stream over.",
        soft_wrap=True,
    )
    # Plain prints, flushed: scripts (and the tests) wait for these lines.
    print(f"live view: {summary['live_url']}", flush=True)
    print("the daemon and the simulated camera keep running; Ctrl-C to stop", flush=True)
    signame = _wait_for_stop(daemon)
    if signame is None:
        raise DemoFailed(
            f"the daemon exited while kept running (exit status {daemon.stop()}); "
            f"see its log {daemon.log_path}"
        )
    record["signal"] = signame
    console.print(f"{signame}: stopping the stream and the daemon")
    try:
        client.stop_stream()
        record["stream_stopped"] = "by the demo"
    except CamdError as exc:
        # Someone took control (the page): the daemon stops the stream as it stops.
        record["stream_stopped"] = f"by the daemon as it stopped ({exc.code}: {exc.message})"


def _wait_for_stop(daemon: DaemonProcess) -> str | None:
    """Wait for SIGINT or SIGTERM (their name) or for the daemon to exit (None)."""
    got: list[str] = []
    stop = threading.Event()

    def handler(signum: int, frame: object) -> None:
        got.append(signal.Signals(signum).name)
        stop.set()

    previous = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        while not stop.wait(0.5):
            if not daemon.running:
                return None
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
    return got[0]


def at_most_once(before: dict[str, Any], after: dict[str, Any]) -> dict[str, Any]:
    """Compare host and device link counters between two ``/link`` snapshots.

    Without a failed command, every command the device executed was answered once on the host
    (ACK or NAK); a retry after a lost acknowledge is answered from the device's record
    (``replayed``), not executed again. So ``executed`` and ``acked + nacked`` grow alike, up to
    the few commands in flight at the snapshots.
    """

    def delta(side: str, key: str) -> int:
        if after.get(side) is None or before.get(side) is None:
            raise DemoFailed(
                f"the daemon could not read the {side}'s link counters; "
                "is the simulated camera still connected? (see the daemon's log)"
            )
        new = (after.get(side) or {}).get(key)
        old = (before.get(side) or {}).get(key)
        if not isinstance(new, int) or not isinstance(old, int):
            raise DemoFailed(
                f"the /link document lacks {side}.{key}; the daemon and this client disagree "
                "on the API (docs/api.md)"
            )
        return new - old

    answered = delta("host", "acked") + delta("host", "nacked")
    executed = delta("device", "executed")
    difference = executed - answered
    failed = delta("host", "failed")
    return {
        "host_sent": delta("host", "sent"),
        "host_acked": delta("host", "acked"),
        "host_nacked": delta("host", "nacked"),
        "host_answered": answered,
        "host_retries": delta("host", "retries"),
        "host_timeouts": delta("host", "timeouts"),
        "host_failed": failed,
        "device_executed": executed,
        "device_replayed": delta("device", "replayed"),
        "difference": difference,
        "tolerance": AT_MOST_ONCE_SLACK,
        # A failed command may have executed without an answer: the check needs none failed.
        "held": failed == 0 and abs(difference) <= AT_MOST_ONCE_SLACK,
    }


def _plain(doc: Mapping[str, Any]) -> dict[str, Any]:
    """A TypedDict document as a plain dict (the summary holds them as such)."""
    return dict(doc)


def _ms(value: Any) -> str:
    return f"{value:.2f}" if isinstance(value, int | float) else "-"


def _seconds(value: Any) -> str:
    if not isinstance(value, int | float):
        return "-"
    return f"{value:.1f} s"
