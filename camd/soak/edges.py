"""``camd soak --edges``: the soak at the edges (a benchmark, not a test): a daemon whose data
disk fills up and empties again while campaign jobs run and emergency stops come every few
minutes, to show that nothing crashes, nothing moves after an emergency stop until it is
released, and every file written stays readable.

``EdgeSoak.run()`` mounts a small tmpfs (``disk_mb``; root only) as the daemon's data
directory, starts ``camd serve --sim`` on it (hr400, a 32-row window) and, for ``minutes``:

- runs the shipped campaign ``example_stare`` as a daemon job, again and again, with stares and
  scans recorded to the data disk between jobs;
- every ``estop_every_s`` (give or take a fifth, seeded), while a job is inside an acquisition,
  asks for an emergency stop; then, for ``watch_s``, checks every quarter second that nothing
  moves or acquires (the wheel's speed, the stage's state and speed, the stream) and that
  turning the wheel is refused; then releases the latch and resumes the job;
- ``disk_fills`` times (spread over the run) fills the data disk to the last page, holds it full
  for ``fill_hold_s`` while the workload goes on (its recordings then fail with a clear error),
  and empties it again.

At the end the daemon is stopped and every HDF5 file on the disk is opened and counted. The
result document's verdicts: no crash (the daemon alive throughout and exiting 0), no motion
after an emergency stop without a release, every file openable, no internal error (500) and
no request left unanswered.
"""

from __future__ import annotations

import collections
import contextlib
import os
import shutil
import subprocess
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py

import camd.store  # noqa: F401  (its compression filters registered before a file is opened)
from camd.cli._daemon_proc import DaemonProcess
from camd.client import CamdError
from camd.soak.workload import SoakAborted, SoakRun, _CountingClient, write_hr400_config

__all__ = ["EdgeSettings", "EdgeSoak", "fill_disk", "mounted_tmpfs"]

CAMPAIGN = "example_stare"
WINDOW_ROWS = 32
POLL_S = 0.25
KEEP_JOBS = 3  # job directories kept on the disk (older ones removed once checked)
KEEP_FILES = 4  # recordings kept on the disk (older ones removed once checked)
REFUSED_PAUSE_S = 1.0  # after a refused job or recording, before the next try
SETTLE_S = 0.5  # after the stop answered, before the checks that nothing moves
JOB_WAIT_S = 180.0


@contextlib.contextmanager
def mounted_tmpfs(folder: Path, size_mb: int) -> Iterator[Path]:
    """A tmpfs of ``size_mb`` MiB mounted on ``folder`` (root only), unmounted afterwards;
    OSError saying why it cannot be mounted."""
    folder.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0:
        raise OSError("mounting a small file system needs root")
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size_mb}m,mode=0755", "tmpfs", str(folder)],
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode != 0:
        raise OSError(f"cannot mount a tmpfs on {folder}: {done.stderr.strip()}")
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=False)


def fill_disk(folder: Path, name: str = "filler") -> int:
    """Write zeros to ``folder/name`` until the disk is full; the bytes written."""
    fd = os.open(folder / name, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    written = 0
    try:
        for size in (1 << 20, 4096):  # big blocks, then down to the last page
            block = bytes(size)
            try:
                while True:
                    written += os.write(fd, block)
            except OSError:
                pass
    finally:
        os.close(fd)
    return written


@dataclass
class EdgeSettings:
    """What ``camd soak --edges`` was asked for."""

    minutes: float
    seed: int
    work_dir: Path
    disk_mb: int = 64
    estop_every_s: float = 180.0
    watch_s: float = 5.0
    disk_fills: int = 2
    fill_hold_s: float = 120.0
    timeout_s: float = 60.0


class EdgeSoak(SoakRun[EdgeSettings]):
    """One edge soak (module docstring); ``progress`` gets a line of text now and then."""

    def __init__(self, settings: EdgeSettings, progress: Callable[[str], None]) -> None:
        super().__init__(settings, progress)
        self.counts: collections.Counter[str] = collections.Counter()
        self.violations: list[str] = []
        self.files: dict[str, Any] = {"checked": 0, "unopenable": []}
        self.checked: set[Path] = set()
        self.job_dirs: list[Path] = []
        self.t0 = 0.0
        self.fill_at: list[float] = []
        self.fill_until: float | None = None
        self.next_estop = 0.0
        self.nominal_deg_s = 0.0

    # -- the run --------------------------------------------------------------------------------

    def run(self) -> dict[str, Any]:
        """Run it; the result document. SoakAborted if the disk cannot be mounted or the
        daemon does not start."""
        disk = self.s.work_dir / "disk"
        try:
            with mounted_tmpfs(disk, self.s.disk_mb):
                self._run_on(disk)
        except OSError as exc:
            raise SoakAborted(f"{exc}; `camd soak --edges` must run as root") from None
        return self.result()

    def _run_on(self, disk: Path) -> None:
        config = write_hr400_config(self.s.work_dir, self.s.seed)
        daemon = DaemonProcess(
            disk,
            extra_args=["--config", str(config)],
            env={"CAMD_TOKEN": ""},
            log_name="../daemon.log",  # beside the disk: a full disk must not stop the log
            start_timeout_s=120.0,
        )

        def empty_disk() -> None:
            with contextlib.suppress(OSError):
                (disk / "filler").unlink(missing_ok=True)

        self._on_daemon(daemon, lambda: self._loop(disk), tidy=empty_disk)
        # What is left on the disk once the daemon has stopped (its files closed).
        self.checked.clear()
        self._check(sorted(disk.rglob("*.h5")))
        journal = disk / "open-recordings"
        self.files["journal_left"] = (
            sorted(p.name for p in journal.iterdir()) if journal.is_dir() else []
        )

    def _loop(self, disk: Path) -> None:
        assert self.daemon is not None
        self.client = c = _CountingClient(
            self.daemon.url, timeout_s=self.s.timeout_s, client="camd-soak-edges"
        )
        c.wait_ready(120.0)
        c.write_registers({"WIN_ROWS": WINDOW_ROWS})
        self.nominal_deg_s = float(c.wheel()["nominal_speed_deg_s"])
        self.t0 = time.monotonic()
        run_s = self.s.minutes * 60.0
        self.fill_at = [
            self.t0 + run_s * (k + 0.5) / (self.s.disk_fills + 1) for k in range(self.s.disk_fills)
        ]
        self.next_estop = self.t0 + self._estop_gap()
        self.progress(
            f"soak --edges: daemon pid {self.daemon.pid} at {self.daemon.url}, data disk {disk} "
            f"({self.s.disk_mb} MiB tmpfs); {self.s.minutes:g} min, an emergency stop every "
            f"~{self.s.estop_every_s:g} s, the disk filled {self.s.disk_fills} times"
        )
        deadline = self.t0 + run_s
        while time.monotonic() < deadline:
            self._alive()
            self._disk(disk)
            self._job()
            self._alive()
            self._disk(disk)
            self._recording(disk)
            self._line()

    def _alive(self) -> None:
        try:
            super()._alive()
        except SoakAborted:
            self.counts["crashes"] += 1
            raise

    def _estop_gap(self) -> float:
        return self.s.estop_every_s * self.rng.uniform(0.8, 1.2)

    # -- the disk -------------------------------------------------------------------------------

    def _disk(self, disk: Path) -> None:
        now = time.monotonic()
        if self.fill_until is not None and now >= self.fill_until:
            (disk / "filler").unlink(missing_ok=True)
            self.fill_until = None
            self.counts["disk_emptied"] += 1
            self.progress(f"[{self._minutes():6.1f} min] data disk emptied")
        elif self.fill_until is None and self.fill_at and now >= self.fill_at[0]:
            self.fill_at.pop(0)
            written = fill_disk(disk)
            self.fill_until = now + self.s.fill_hold_s
            self.counts["disk_filled"] += 1
            self.progress(
                f"[{self._minutes():6.1f} min] data disk filled ({written / 2**20:.1f} MiB "
                f"written), held full for {self.s.fill_hold_s:g} s"
            )

    # -- campaign jobs and emergency stops --------------------------------------------------------

    def _job(self) -> None:
        assert self.client is not None
        c = self.client
        try:
            job = c.start_campaign(CAMPAIGN, quick=True)
        except CamdError as exc:
            self.counts["jobs_refused"] += 1
            self._note_refusal(exc)
            time.sleep(REFUSED_PAUSE_S)  # a full disk refuses at once: not thousands a minute
            return
        self.counts["jobs_started"] += 1
        job_id = int(job["id"])
        ended = ("paused", "aborted", "passed", "failed", "error", "interrupted")
        deadline = time.monotonic() + JOB_WAIT_S
        while time.monotonic() < deadline:
            doc = c.campaign_job(job_id)
            if doc["state"] in ended:
                break
            if time.monotonic() >= self.next_estop and "acquire" in (doc["activity"] or ""):
                self._estop(job_id)
                self.next_estop = time.monotonic() + self._estop_gap()
                deadline = time.monotonic() + JOB_WAIT_S  # resumed: a new run
            time.sleep(POLL_S)
        final = c.campaign_job(job_id)
        self.counts[f"jobs_{final['state']}"] += 1
        if final["state"] not in ended:
            with contextlib.suppress(CamdError):
                c.abort_campaign(job_id)
        # Its files are checked now and then removed (but the last few), so that the disk fills
        # when the soak fills it, not by itself.
        out = Path(str(final["out_dir"]))
        self._check(sorted(out.rglob("*.h5")))
        self.job_dirs.append(out)
        while len(self.job_dirs) > KEEP_JOBS:
            shutil.rmtree(self.job_dirs.pop(0), ignore_errors=True)

    def _estop(self, job_id: int) -> None:
        """The stop, then ``watch_s`` of checking that nothing moves, then the release."""
        assert self.client is not None
        c = self.client
        stop = c.estop()
        self.counts["estops"] += 1
        if stop["failed"]:
            self.violations.append(f"emergency stop could not stop: {stop['failed']}")
        time.sleep(SETTLE_S)  # what the stop ended may take a moment to say it has
        end = time.monotonic() + self.s.watch_s
        while time.monotonic() < end:
            wheel = float(c.wheel()["speed_deg_s"])
            reading = c.motion()["reading"]
            streaming = bool(c.stream()["streaming"])
            if wheel != 0.0 or reading["speed_m_s"] != 0.0 or streaming:
                self.violations.append(
                    f"{self._minutes():.1f} min: after the emergency stop, without a release: "
                    f"wheel {wheel:g} deg/s, stage {reading['state']} at "
                    f"{reading['speed_m_s']:g} m/s, streaming {streaming}"
                )
            self.counts["estop_checks"] += 1
            time.sleep(POLL_S)
        try:
            c.set_wheel_speed(self.nominal_deg_s)
            self.violations.append("the wheel was turned while the emergency stop was latched")
        except CamdError as exc:
            if exc.code == "estop_latched":
                self.counts["refused_while_latched"] += 1
            else:
                self.violations.append(f"turning the wheel while latched: {exc.code}")
        job = c.campaign_job(job_id)
        self.counts[f"estop_job_{job['state']}"] += 1
        c.release_estop()
        c.enable_stage(True)
        self.progress(f"[{self._minutes():6.1f} min] emergency stop: job {job_id} {job['state']}")
        deadline = time.monotonic() + JOB_WAIT_S
        while c.campaign_job(job_id)["state"] in ("running", "pausing"):
            if time.monotonic() > deadline:
                self.violations.append(f"job {job_id} still running {JOB_WAIT_S:g} s after a stop")
                return
            time.sleep(POLL_S)
        if c.campaign_job(job_id)["state"] == "paused":
            try:
                c.resume_campaign(job_id)
                self.counts["jobs_resumed"] += 1
            except CamdError as exc:
                self._note_refusal(exc)

    # -- recordings -----------------------------------------------------------------------------

    def _recording(self, disk: Path) -> None:
        assert self.client is not None
        c = self.client
        folder = disk / "files"
        with contextlib.suppress(OSError):
            folder.mkdir(exist_ok=True)
        n = self.counts["recordings"]
        self.counts["recordings"] += 1
        try:
            if self.rng.random() < 0.5:
                path = folder / f"stare-{n}.h5"
                c.acquire(self.rng.randint(5, 30), mode="area", record=str(path), timeout_s=60)
            else:
                path = folder / f"scan-{n}.h5"
                period = float(c.timing()["line_period_s"]) * WINDOW_ROWS
                c.start_scan(
                    8, self.rng.randint(100, 300), out=str(path), line_period_s=period,
                    quicklook=False, drive_stage=False,
                )  # fmt: skip
                c.wait_scan(120.0)
            self.counts["recordings_ok"] += 1
        except CamdError as exc:
            self._note_refusal(exc)
            with contextlib.suppress(CamdError):
                c.stop_scan()
            time.sleep(REFUSED_PAUSE_S)
        # Checked now, then removed but for the last few: the disk fills when the soak fills it.
        made = sorted(folder.glob("*.h5"), key=lambda p: p.stat().st_mtime)
        self._check([p for p in made if p not in self.checked])
        for old in made[:-KEEP_FILES]:
            old.unlink(missing_ok=True)

    def _check(self, paths: list[Path]) -> None:
        for path in paths:
            problem = _unopenable(path)
            self.files["checked"] += 1
            if problem is not None:
                self.files["unopenable"].append(problem)
            self.checked.add(path)

    def _note_refusal(self, exc: CamdError) -> None:
        key = "disk_full" if "full" in exc.message or "space" in exc.message else exc.code
        self.counts[f"refused_{key}"] += 1

    # -- bookkeeping ----------------------------------------------------------------------------

    def _minutes(self) -> float:
        return (time.monotonic() - self.t0) / 60.0

    def _line(self) -> None:
        assert self.client is not None
        if self.counts["lines"] % 10 == 0:
            counts = self.client.counts
            self.progress(
                f"[{self._minutes():6.1f} min] jobs {self.counts['jobs_started']}, emergency "
                f"stops {self.counts['estops']}, recordings {self.counts['recordings']} "
                f"({self.counts['recordings_ok']} ok), requests {counts['sent']} "
                f"({counts['5xx']} 5xx), violations {len(self.violations)}"
            )
        self.counts["lines"] += 1

    def result(self) -> dict[str, Any]:
        """The result document (docs/cli.md, ``camd soak --edges``)."""
        daemon = self.daemon
        log = daemon.log_path if daemon is not None else None
        tracebacks = 0
        if log is not None and log.exists():
            tracebacks = log.read_text(errors="replace").count("Traceback")
        answered = self.client.counts if self.client is not None else collections.Counter[str]()
        codes = self.client.codes if self.client is not None else collections.Counter[str]()
        counts = {k: v for k, v in sorted(self.counts.items()) if k != "lines"}
        exit_code = daemon.exit_code if daemon is not None else None
        crashes = counts.get("crashes", 0) + (0 if exit_code in (0, None) else 1)
        verdict = {
            "crashes_0": crashes == 0 and exit_code == 0,
            "motion_after_estop_0": not self.violations and counts.get("estops", 0) > 0,
            "files_openable": self.files.get("unopenable") == [],
            # 5xx answers that say what happened (507 a full disk, 502 a stream ended early)
            # are the daemon working; 500 is a bug, a request unanswered a hang.
            "no_internal_error": codes["internal"] == 0 and answered["no_answer"] == 0,
        }
        return {
            "minutes": self.s.minutes,
            "seconds": round(time.monotonic() - self.t0, 1) if self.t0 else 0.0,
            "seed": self.s.seed,
            "disk_mb": self.s.disk_mb,
            "interrupted": self.interrupted,
            "error": self.error,
            "daemon": {
                "log": str(log) if log is not None else None,
                "exit_code": exit_code,
                "tracebacks_in_log": tracebacks,
            },
            "counts": counts,
            "crashes": crashes,
            "requests": {k: answered[k] for k in ("sent", "2xx", "4xx", "5xx", "no_answer")},
            "error_codes": dict(sorted(codes.items())),
            "violations": self.violations,
            "files": self.files,
            "verdict": verdict,
        }


def _unopenable(path: Path) -> str | None:
    """Why the HDF5 file ``path`` cannot be opened and its data's shape read (None: it can)."""
    try:
        with h5py.File(path, "r") as f:
            for name in ("frames", "lines"):
                if name in f:
                    _ = f[name].shape
    except FileNotFoundError:
        return None  # removed meanwhile (a stopped job's step file made anew)
    except Exception as exc:  # any failure to read is what is counted
        return f"{path}: {type(exc).__name__}: {exc}"
    return None
