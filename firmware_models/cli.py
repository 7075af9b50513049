"""Command line of the simulated camera: ``python -m firmware_models`` (and ``camd sim``).

Prints exactly one line saying where the camera listens (JSON with ``--json``), then serves
until SIGTERM or SIGINT, and exits 0. ``main(argv)`` returns the exit status instead of exiting
so that ``camd sim`` can call it in-process.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import FrameType

from camd.datafile import DataFileError, bounded
from camd.protocol import load_dictionary
from camd.sensor.profile import list_profiles
from firmware_models.defects import DEFECTS, Defects
from firmware_models.fpga import FpgaModel
from firmware_models.fx3 import StreamSocketServer
from firmware_models.inject import FaultInjector, InjectSpec
from firmware_models.pty_server import PtyServer
from firmware_models.scene_spec import SceneSpec
from firmware_models.usb_spi import SpiSocketServer

DEFAULT_PROFILE = "hr400"
WARM_UP_ENV = "CAMD_SIM_WARM_UP"
"""Environment variable: ``0`` leaves the camera's first-frame work (compiled kernels, fixed
pattern, noise bank: about a second of one core) to the first stream instead of doing it on a
thread when the simulator starts (the test suite sets it: most of its simulators stream little
or never)."""
_PROFILE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
_STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT)


def _inject_arg(text: str) -> InjectSpec:
    try:
        return InjectSpec.parse(text)
    except ValueError as exc:
        # ArgumentTypeError, unlike ValueError, makes argparse print our message verbatim.
        raise argparse.ArgumentTypeError(str(exc)) from None


def _scene_arg(text: str) -> SceneSpec:
    try:
        return SceneSpec.parse(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _period_arg(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not value >= 0.0:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a period in seconds; give a number >= 0 (0 disables telemetry)"
        )
    return value


def _profile_arg(text: str) -> str:
    if not _PROFILE_NAME.match(text):
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a profile name; use letters, digits, '_', '-' or '.' (e.g. hr400)"
        )
    known = list_profiles()
    if text not in known:
        # The profile (config/profiles/) names the camera physics and the register map.
        raise argparse.ArgumentTypeError(
            f"no simulated camera profile {text!r}; known: {', '.join(known)}"
        )
    return text


def build_parser(prog: str = "python -m firmware_models") -> argparse.ArgumentParser:
    """The argument parser of ``python -m firmware_models``."""
    parser = argparse.ArgumentParser(
        prog=prog,
        description="Run the simulated camera FPGA on a pseudo-terminal (RS-422 command link).",
    )
    parser.add_argument(
        "--profile",
        type=_profile_arg,
        default=DEFAULT_PROFILE,
        help=f"camera profile name (default {DEFAULT_PROFILE})",
    )
    parser.add_argument(
        "--inject",
        type=_inject_arg,
        default=InjectSpec(),
        metavar="SPEC",
        help="line faults, e.g. 'ber=1e-4,drop=0.01,garbage=0.001,delay_ms=2' (default: none)",
    )
    parser.add_argument(
        "--link",
        type=Path,
        default=None,
        metavar="PATH",
        help="also make PATH a symlink to the pty, so a host can reconnect to a new simulator",
    )
    parser.add_argument(
        "--hk-period-s",
        type=_period_arg,
        default=1.0,
        metavar="S",
        help="period of unsolicited HOUSEKEEPING telemetry in seconds; 0 disables (default 1.0)",
    )
    parser.add_argument(
        "--spi-socket",
        type=Path,
        default=None,
        metavar="PATH",
        help="also serve the sensor's SPI bus on a Unix socket at PATH, for a host driving a "
        "simulated USB-SPI bridge (firmware_models.mcp2210_backend.SocketSpiTarget)",
    )
    parser.add_argument(
        "--usb-socket",
        type=Path,
        default=None,
        metavar="PATH",
        help="serve the USB bulk frame stream on a Unix socket at PATH, for a host using the "
        "simulated FX3 backend (firmware_models.fx3_backend.get_backend)",
    )
    parser.add_argument(
        "--scene",
        type=_scene_arg,
        default=None,
        metavar="SPEC",
        help="scene in front of the camera, e.g. 'bars:lux=3' or 'flat:photons=2e4' "
        "(default: a flat field; docs/simulator.md lists the scenes)",
    )
    parser.add_argument(
        "--frame-bank",
        type=int,
        default=0,
        metavar="K",
        help="render the first K frames of each stream and replay them in a loop with fresh "
        "headers (throughput tests at line rates the renderer cannot reach; 0 = render all)",
    )
    parser.add_argument(
        "--stage",
        default="linear_rail",
        metavar="NAME",
        help="the scan stage's mechanics, config/stages/NAME.toml (default linear_rail)",
    )
    parser.add_argument(
        "--defect",
        action="append",
        default=[],
        choices=sorted(DEFECTS),
        metavar="NAME",
        help="turn on a deliberate defect (repeatable; docs/conformance.md): " + ", ".join(DEFECTS),
    )
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--json", action="store_true", help="print the start line as JSON")
    return parser


def main(argv: list[str] | None = None, *, prog: str = "python -m firmware_models") -> int:
    """Run the simulator until SIGTERM/SIGINT; return the exit status (2 for bad arguments)."""
    parser = build_parser(prog)
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, or a usage error already printed to stderr
        return exc.code if isinstance(exc.code, int) else 2

    inject: InjectSpec = args.inject
    link: Path | None = Path(os.path.abspath(args.link)) if args.link is not None else None
    spi_path: Path | None = (
        Path(os.path.abspath(args.spi_socket)) if args.spi_socket is not None else None
    )
    usb_path: Path | None = (
        Path(os.path.abspath(args.usb_socket)) if args.usb_socket is not None else None
    )
    try:
        model = FpgaModel(
            load_dictionary(),
            seed=args.seed,
            power_on_s=time.monotonic(),
            injector=FaultInjector(inject, seed=args.seed),
            sensor=args.profile,
            stage=args.stage,
            defects=Defects.parse(args.defect),
        )
    except DataFileError as exc:  # a config file: its file:line message says what to change
        print(f"{prog}: error: {bounded(str(exc))}", file=sys.stderr)
        return 2
    if args.scene is not None:
        model.camera.set_scene(args.scene)
    if args.frame_bank < 0:
        parser.print_usage(sys.stderr)
        print(f"{prog}: error: --frame-bank must be >= 0", file=sys.stderr)
        return 2
    model.imaging_path.frame_bank = args.frame_bank
    server = PtyServer(model, link=link, hk_period_s=args.hk_period_s)
    with _stop_on_signals(server):
        spi_server = (
            SpiSocketServer(spi_path, model.spi_slave, model.lock) if spi_path is not None else None
        )
        usb_server = StreamSocketServer(usb_path) if usb_path is not None else None
        try:
            tty_path = server.open()
            if spi_server is not None:
                spi_server.start()
            if usb_server is not None:
                usb_server.start()
                model.attach_stream_server(usb_server)
        except OSError as exc:
            print(f"python -m firmware_models: cannot start: {exc}", file=sys.stderr)
            server.close()
            return 1
        try:
            print(
                _start_line(args.json, tty_path, link, args.profile, inject, spi_path, usb_path),
                flush=True,
            )
            if os.environ.get(WARM_UP_ENV, "1") != "0":
                threading.Thread(
                    target=_warm_up, args=(model,), name="warm-up", daemon=True
                ).start()
            server.serve()
        finally:
            model.close()
            if usb_server is not None:
                usb_server.stop()
            if spi_server is not None:
                spi_server.stop()
            server.close()
    return 0


def _warm_up(model: FpgaModel) -> None:
    """The camera's first-frame work, ahead of the first stream (``CameraModel.warm_up``); a
    failure here only means the first stream does it (and says why, if it fails again)."""
    try:
        model.camera.warm_up()
    except Exception as exc:  # the stream reports a real failure; here it is only early
        print(f"python -m firmware_models: warm-up skipped: {bounded(str(exc))}", file=sys.stderr)


def _start_line(
    as_json: bool,
    tty_path: str,
    link: Path | None,
    profile: str,
    inject: InjectSpec,
    spi_socket: Path | None = None,
    usb_socket: Path | None = None,
) -> str:
    if as_json:
        return json.dumps(
            {
                "tty": tty_path,
                "link": str(link) if link is not None else None,
                "pid": os.getpid(),
                "profile": profile,
                "inject": inject.model_dump(),
                "spi_socket": str(spi_socket) if spi_socket is not None else None,
                "usb_socket": str(usb_socket) if usb_socket is not None else None,
            }
        )
    where = f"{tty_path} (link {link})" if link is not None else tty_path
    spi = f"; sensor SPI on {spi_socket}" if spi_socket is not None else ""
    spi += f"; USB stream on {usb_socket}" if usb_socket is not None else ""
    return (
        f"simulated camera (profile {profile}) listening on {where}{spi}; "
        f"inject {inject.describe()}; Ctrl-C to stop"
    )


@contextmanager
def _stop_on_signals(server: PtyServer) -> Iterator[None]:
    """SIGTERM/SIGINT stop the server cleanly; the previous handlers come back afterwards."""
    if threading.current_thread() is not threading.main_thread():
        yield  # only the main thread may set handlers; the caller stops the server itself
        return

    def handler(signum: int, frame: FrameType | None) -> None:
        server.stop()

    previous = {sig: signal.signal(sig, handler) for sig in _STOP_SIGNALS}
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
