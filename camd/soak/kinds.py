"""The kinds of item of ``camd soak``'s workload (camd.soak.workload runs them): each makes its
requests through the soak's client, checks what came back (a read-back, the device's CRCs, a
campaign's checks) and counts the frames of its acquisitions.

A kind raises ``CamdError`` for a refused request and ``CheckFailed`` for a failed check; the
soak counts the item as failed and recovers.
"""

from __future__ import annotations

import collections
import random
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from camd.client import CamdClient

WINDOW_ROWS = 32  # a small window keeps frames cheap for the simulator's renderer
CAMPAIGN = "example_stare"  # run --quick
DEFAULT_GAIN = 0x0040  # hr400 reset values (config/sensors/hr400.toml)
DEFAULT_OFFSET = 100
SCAN_TIMEOUT_S = 120.0
# The host's counters of frames of a stream never delivered (docs/stream.md: each counter of a
# stream is exactly one of delivered, lost, corrupt, short, overruns).
MISSING_KINDS = ("lost", "corrupt", "short", "overruns")


class CheckFailed(Exception):
    """A workload item's own check failed (read-back, CRC, a campaign check)."""


@dataclass
class Frames:
    """The frames of the soak's acquisitions, as the host counted them."""

    acquisitions: int = 0
    produced_requested: int = 0
    delivered: int = 0
    host: collections.Counter[str] = field(default_factory=collections.Counter)

    def count(self, requested: int, stats: dict[str, Any]) -> None:
        """Add one acquisition of ``requested`` frames, its host counters ``stats``."""
        self.acquisitions += 1
        self.produced_requested += requested
        self.delivered += int(stats.get("frames", 0))
        for key in (*MISSING_KINDS, "stalls", "out_of_order"):
            self.host[key] += int(stats.get(key, 0))


@dataclass(eq=False)
class WorkloadKinds:
    """The workload's items, one method a kind (``ping``, ``stream``, ...), each given the
    item's number (the name of the files it makes). ``client`` makes the requests, ``rng``
    draws their sizes, ``work_dir`` holds their files, ``frames`` counts their frames;
    ``line_period_s`` is the registers' line period (a scan runs at a multiple of it)."""

    client: CamdClient
    rng: random.Random
    work_dir: Path
    frames: Frames
    line_period_s: float

    def run(self, kind: str, item: int) -> None:
        """Run item number ``item``, of ``kind``."""
        getattr(self, kind)(item)

    def ping(self, item: int) -> None:
        count = self.rng.randint(10, 50)
        # Payloads up to 64 bytes, the size of the daemon's own commands: at BER 1e-4 a
        # 256-byte frame is hit in 19 % of its crossings each way, and the link's 6 attempts
        # then fail about once in 250 pings, a figure of the line, not of the daemon.
        doc = self.client.ping(count=count, size=self.rng.choice((0, 16, 64)))
        if doc["failed"] or doc["ok"] != count:
            raise CheckFailed(
                f"{doc['failed']} of {count} pings failed: {'; '.join(doc['errors'])}"
            )

    def telemetry(self, item: int) -> None:
        c = self.client
        c.status()
        latest = c.telemetry()["latest"]
        if latest:
            channel = self.rng.choice(sorted(latest))
            c.history(channel, since_s=-60.0, limit=100)
        c.events(limit=20)
        c.link()
        c.timing()
        c.stream()
        c.scan()
        c.motion()
        c.sim_stream_stats()
        c.metrics()

    def registers(self, item: int) -> None:
        c = self.client
        wanted = {
            "GAIN": (self.rng.randint(0, 3) << 8) | self.rng.randint(32, 255),
            "OFFSET": self.rng.randint(0, 1023),
        }
        for values in (wanted, {"GAIN": DEFAULT_GAIN, "OFFSET": DEFAULT_OFFSET}):
            c.write_registers(dict(values))
            for name, value in values.items():
                got = c.read_register(name)["value"]
                if got != value:
                    raise CheckFailed(f"{name} reads back {got} after writing {value}")

    def stream(self, item: int) -> None:
        frames = self.rng.randint(100, 400)
        stages = self.rng.choice((4, 8, 16, WINDOW_ROWS))
        doc = self.client.acquire(frames, mode="tdi", stages=stages, timeout_s=60.0)
        self.frames.count(frames, dict(doc["stats"]))

    def stare(self, item: int) -> None:
        from camd.store.recording_reading import read_recording

        frames = self.rng.randint(5, 30)
        path = self._new_file(f"stare-{item}.h5")
        doc = self.client.acquire(frames, mode="area", record=str(path), timeout_s=60.0)
        stats = dict(doc["stats"])
        self.frames.count(frames, stats)
        recording = read_recording(path)
        bad = recording.crc_mismatches()
        if bad or len(recording.frames) != stats["frames"]:
            raise CheckFailed(
                f"{path}: {len(recording.frames)} frames read back for {stats['frames']} "
                f"delivered, {len(bad)} differing from the device's CRC (file kept)"
            )
        path.unlink()

    def scan(self, item: int) -> None:
        c = self.client
        stages = self.rng.choice((1, 8, 16, WINDOW_ROWS))
        lines = self.rng.randint(100, 400)
        quicklook = self.rng.random() < 0.5
        path = self._new_file(f"scan-{item}.h5")
        c.start_scan(
            stages, lines, out=str(path), line_period_s=WINDOW_ROWS * self.line_period_s,
            quicklook=quicklook, drive_stage=False,
        )  # fmt: skip
        doc = c.wait_scan(SCAN_TIMEOUT_S)
        self.frames.count(int(doc["frames_requested"]), dict(doc["stream"]))
        if doc["state"] != "done":
            raise CheckFailed(f"scan {path} ended {doc['state']}: {doc['error']} (file kept)")
        path.unlink(missing_ok=True)
        path.with_suffix(".png").unlink(missing_ok=True)

    def campaign(self, item: int) -> None:
        from camd.campaign.loading import load_campaign
        from camd.campaign.runner import CampaignRunner
        from camd.campaign.spec import CampaignError
        from camd.cli.camctl_campaign import campaigns_dir
        from camd.store.recording_reading import read_recording

        out = self.work_dir / f"campaign-{item}"
        spec = load_campaign(campaigns_dir() / f"{CAMPAIGN}.yaml")
        try:
            outcome = CampaignRunner(self.client, spec, out, quick=True, sim=True).run()
            passed, why = outcome.passed, "a check failed"
        except CampaignError as exc:
            passed, why = False, str(exc)
        finally:
            # Its stares' host counters are in the recordings it made.
            for path in sorted((out / "raw").glob("*.h5")):
                stream = read_recording(path).metadata.get("stream", {})
                self.frames.count(int(stream.get("frames_requested", 0)), stream)
            # The campaign seeds the simulator per step: vary the faults that follow it.
            self.client.set_sim_seed(self.rng.randrange(2**31))
        if not passed:
            raise CheckFailed(f"campaign {CAMPAIGN} --quick failed: {why} (kept in {out})")
        shutil.rmtree(out)

    def _new_file(self, name: str) -> Path:
        path = self.work_dir / "files" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.unlink(missing_ok=True)
        return path
