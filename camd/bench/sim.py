"""``camd bench sim``: how fast can the simulated camera make frames, against the sensor?

For each camera profile and each number of window rows M, the simulated FPGA (the same
imaging path, stream engine and stream socket the simulator runs) streams unpaced, as fast as
it can, into a reader in its own process that only reads (``recv_into`` one buffer: a reader
that costs next to nothing, so the simulator is what is measured). The baseline is the sensor: the
fastest line rate M rows allow (window of M rows, the shortest exposure: one frame per
``max(M, 2)`` line periods, docs/physics.md §3). The ratio says how far the simulator outruns
the sensor; under 1, a scan on the simulator is paced by the simulator, not the sensor, and
"no frame lost" proves nothing about the host.

Two kinds of frames: ``bank`` replays a bank of rendered frames with fresh headers (what
``[sim] frame_bank`` and ``camd bench scan`` use), ``render`` renders every frame from the
scene (the physics: noise, motion, the LVDS link, trained as the daemon trains it when it
connects).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from camd.bench.common import thread_cpu_s, window_stages
from camd.protocol.stream import HEADER_BYTES

DEFAULT_PROFILES = ("hr400", "ibis5", "ftf5066", "uvccd", "mt9m001")
DEFAULT_STAGES = (1, 8, 32, 96)  # 1: each profile's fastest line rate (the fewest rows)
DEFAULT_BANK = 64
WARM_UP_S = 0.5


def add_options(p: argparse.ArgumentParser) -> None:
    """The options of ``camd bench sim`` but ``--json`` (camd.bench.command adds it)."""
    p.add_argument(
        "--profiles",
        default=",".join(DEFAULT_PROFILES),
        help=f"camera profiles, comma-separated (default {','.join(DEFAULT_PROFILES)})",
    )
    p.add_argument(
        "--stages",
        default=",".join(str(m) for m in DEFAULT_STAGES),
        help="window rows M, comma-separated (default 1,8,32,96; within the rows a sensor's "
        "window allows)",
    )
    p.add_argument(
        "--kinds",
        default="bank,render",
        help="bank (replayed frames, as bench scan uses) and/or render (default both)",
    )
    p.add_argument("--seconds", type=float, default=2.0, help="measuring time per case (2)")
    p.add_argument(
        "--scene",
        default="",
        help="the scene rendered, e.g. bars:lux=3 (docs/simulator.md; default: a flat field)",
    )


class _SensorBridge:
    """The simulated sensor's own bus, as a register bridge (no link in between)."""

    name = "sim-sensor"

    def __init__(self, fpga: Any) -> None:
        self._fpga = fpga

    def read(self, address: int) -> int:
        with self._fpga.lock:
            return int(self._fpga.sensor.spi_read(address))

    def write(self, address: int, value: int) -> None:
        with self._fpga.lock:
            self._fpga.sensor.spi_write(address, value)

    def write_burst(self, writes: list[tuple[int, int]]) -> None:
        for address, value in writes:
            self.write(address, value)


def _set_window(fpga: Any, rows: int) -> None:
    """A window of ``rows`` rows and the shortest exposure (one line), no back path."""
    from camd.sensor.registers import SensorRegisters

    regmap = fpga.regmap
    writes: dict[str, int | str] = {}
    for role, count in (("window_rows", rows), ("exposure_lines", 1), ("back_path", 0)):
        write = regmap.role_write(role, count)
        if write is not None:
            writes[write[0]] = write[1]
    SensorRegisters(regmap, _SensorBridge(fpga)).write(writes)  # type: ignore[arg-type]


# The reader, in its own process as the host is (a thread here would share the simulator's
# interpreter lock): reads the stream socket into one buffer until it closes.
_DRAIN = """
import socket, sys
s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
s.connect(sys.argv[1])
buf = bytearray(8 << 20)
while s.recv_into(buf):
    pass
"""


def measure(profile: str, rows: int, kind: str, seconds: float, scene: str = "") -> dict[str, Any]:
    """One case: the simulated camera ``profile`` with ``rows`` window rows, unpaced, looking
    at ``scene`` (a flat field if empty)."""
    from firmware_models.fpga import FpgaModel
    from firmware_models.fx3 import StreamSocketServer

    fpga = FpgaModel(seed=1, sensor=profile)
    tmp = Path(tempfile.mkdtemp(prefix="camd-bench-sim-"))
    sock = tmp / "usb.sock"
    server = StreamSocketServer(sock)
    reader: subprocess.Popen[bytes] | None = None
    try:
        _set_window(fpga, rows)
        with fpga.lock:  # as the daemon does when it connects: frames pass the link as sent
            fpga.sensor_link.train()
            if scene:
                fpga.camera.set_scene(scene)
        server.start()
        fpga.stream.server = server
        reader = subprocess.Popen([sys.executable, "-c", _DRAIN, str(sock)])
        if not server.wait_ready(30.0):
            raise RuntimeError("the stream socket took no reader in 30 s")
        path = fpga.imaging_path
        path.frame_bank = DEFAULT_BANK if kind == "bank" else 0
        path.unpaced = True
        engine = fpga.stream
        with fpga.lock:
            geometry = path.start(
                device_time_s=1.0, mode="tdi", frames=0, stages=rows, binning=False
            )
        # Past the first frame (the fixed-pattern maps and the noise drawn on first use, the
        # compiled kernels loaded), then the bank's first renders.
        first_deadline = time.monotonic() + 60.0
        while engine.counters.sent == 0 and time.monotonic() < first_deadline:
            time.sleep(0.05)
        time.sleep(WARM_UP_S)
        thread = engine._thread
        assert thread is not None and thread.native_id is not None
        c = engine.counters
        sent0, bytes0 = c.sent, c.bytes_sent
        cpu0, t0 = thread_cpu_s(thread.native_id), time.perf_counter()
        time.sleep(seconds)
        sent1, bytes1 = c.sent, c.bytes_sent
        cpu1, t1 = thread_cpu_s(thread.native_id), time.perf_counter()
        engine.stop()
        engine.wait_idle(10.0)
    finally:
        fpga.close()
        server.stop()
        if reader is not None:
            reader.wait(10.0)
        shutil.rmtree(tmp, ignore_errors=True)
    elapsed = t1 - t0
    frames_per_s = (sent1 - sent0) / elapsed
    line_rate_hz = 1.0 / geometry.frame_period_s
    return {
        "profile": profile,
        "stages": rows,
        "kind": kind,
        "cols": geometry.cols,
        "frame_bytes": HEADER_BYTES + geometry.rows * geometry.cols * 2,
        "line_rate_hz": line_rate_hz,
        "frames_per_s": frames_per_s,
        "over_line_rate": frames_per_s / line_rate_hz,
        "mbyte_per_s": (bytes1 - bytes0) / elapsed / 1e6,
        "engine_cpu_cores": (cpu1 - cpu0) / elapsed,
        "seconds": elapsed,
    }


def run(args: argparse.Namespace) -> int:
    """``camd bench sim``: print the table (one JSON document with --json)."""
    profiles = [p.strip() for p in args.profiles.split(",") if p.strip()]
    kinds = [k.strip() for k in args.kinds.split(",") if k.strip()]
    try:
        stages = [int(m) for m in args.stages.split(",") if m.strip()]
    except ValueError:
        print(f"camd bench sim: --stages {args.stages!r}: give whole numbers, e.g. 8,32,96")
        return 2
    if not stages or min(stages) < 1 or not args.seconds > 0:
        print("camd bench sim: --stages must be >= 1 and --seconds > 0")
        return 2
    bad = [k for k in kinds if k not in ("bank", "render")]
    if bad or not kinds:
        print(f"camd bench sim: --kinds {args.kinds!r}: use bank, render or bank,render")
        return 2
    from firmware_models.scene_spec import SceneSpec, SceneSpecError

    scene = getattr(args, "scene", "")
    try:
        SceneSpec.parse(scene)
    except SceneSpecError as exc:
        print(f"camd bench sim: --scene {scene!r}: {exc}")
        return 2
    cases = []
    for profile in profiles:
        for m in window_stages(profile, stages):
            for kind in kinds:
                cases.append(measure(profile, m, kind, args.seconds, scene))
                if not args.json:
                    _print_case(cases[-1], header=len(cases) == 1)
    if args.json:
        print(json.dumps({"cases": cases}))
    return 0


def _print_case(c: dict[str, Any], *, header: bool) -> None:
    if header:
        print(
            f"{'profile':<8} {'M':>4} {'kind':<6} {'line rate':>10} {'frames/s':>10} "
            f"{'x line':>7} {'MB/s':>6} {'cores':>5}"
        )
    print(
        f"{c['profile']:<8} {c['stages']:>4} {c['kind']:<6} {c['line_rate_hz']:>8.0f}/s "
        f"{c['frames_per_s']:>8.0f}/s {c['over_line_rate']:>6.2f}x {c['mbyte_per_s']:>6.0f} "
        f"{c['engine_cpu_cores']:>5.2f}"
    )
