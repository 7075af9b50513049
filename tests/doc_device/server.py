"""The doc-built device behind a real pseudo-terminal: the daemon opens the slave side as a
serial port (``link.device`` = ``PtyDevice.port``), as it would a USB-RS422 adapter.

One thread owns the master side: it reads bytes, hands frames to the device, writes the
answers, sends the BOOT event at start, a HOUSEKEEPING packet every ``hk_period_s`` and the
events no command caused (a move finishing, a counted stream ending) when they are due.
"""

from __future__ import annotations

import os
import select
import threading
import time
import tty

from tests.doc_device.device import DocDevice
from tests.doc_device.wire import MAX_PAYLOAD, Frame, Receiver

LINE_RATE_BPS = 921600  # docs/config.md link.baudrate's default; a pty ignores it
MAX_FRAME_S = (MAX_PAYLOAD + 9) * 10 / LINE_RATE_BPS  # §3 rule 5: a maximum frame on the line


class PtyDevice:
    """``DocDevice`` served on a pty; ``start()``, ``port``, ``stop()``."""

    def __init__(self, device: DocDevice | None = None, *, hk_period_s: float = 1.0) -> None:
        self.device = device if device is not None else DocDevice()
        self.receiver = Receiver()
        self.device.receiver_counters = self.receiver.counters
        self.hk_period_s = hk_period_s
        self.lock = threading.Lock()  # tests poke the device (raise_fault) from their thread
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.port = os.ttyname(self._slave)
        self._t0 = time.monotonic()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="doc-device", daemon=True)

    def now_s(self) -> float:
        """Device time: seconds since power-on."""
        return time.monotonic() - self._t0

    def start(self) -> PtyDevice:
        with self.lock:
            self._send(self.device.boot_frames())
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5.0)
        os.close(self._master)
        os.close(self._slave)

    def send_unsolicited(self, frames: list[Frame]) -> None:
        """Frames made outside the loop (a fault a test raises)."""
        self._send(frames)

    def _send(self, frames: list[Frame]) -> None:
        for frame in frames:
            data = frame.encode()
            while data:
                try:
                    data = data[os.write(self._master, data) :]
                except BlockingIOError:
                    time.sleep(0.001)

    def _run(self) -> None:
        next_hk = self.now_s() + self.hk_period_s
        while not self._stop.is_set():
            ready, _, _ = select.select([self._master], [], [], 0.01)
            now = self.now_s()
            data = b""
            if ready:
                try:
                    data = os.read(self._master, 4096)
                except OSError:
                    data = b""  # no reader on the slave side yet (EIO); keep serving
                    time.sleep(0.01)
            with self.lock:
                frames = self.receiver.feed(data, now) if data else []
                frames += self.receiver.expire(now, MAX_FRAME_S)
                out: list[Frame] = []
                for frame in frames:
                    out += self.device.handle(frame, now)
                out += self.device.unsolicited(now)
                if now >= next_hk:
                    out.append(self.device.housekeeping_frame(now))
                    next_hk = now + self.hk_period_s
                self._send(out)
