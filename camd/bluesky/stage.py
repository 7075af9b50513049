"""The scan stage as an ophyd-async motor: Movable, Locatable, Stoppable, Readable, in metres.

``set(x)`` moves the stage to ``x`` m from home (POST /api/v1/motion/move, which answers at
once) and follows the move through GET /api/v1/motion until the stage stands, its position
read back on the way; the move's own end decides, as for ``camctl stage move``
(docs/motion.md). ``stop()`` decelerates it (POST /api/v1/motion/stop). Its readback asks the
daemon on every read, so a plan's readings are the stage's position at that moment.

Staged, it takes the connection's control lease and energises a released motor (the stage is
``disabled`` after power-on), and puts both back when unstaged: a motor it energised is
released again. It never clears an emergency stop: a stage in ``estop`` refuses the stage with
the daemon's words.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from typing import Any

from ophyd_async.core import (
    AsyncStatus,
    MovableLogic,
    SignalR,
    StandardMovable,
    StandardReadable,
    StandardReadableFormat,
    TimeoutCalculator,
    soft_signal_r_and_setter,
    soft_signal_rw,
)

from camd.bluesky.connection import CamdConnection, holder_name
from camd.client.connection import CamdError
from camd.client.motion import (
    STAGE_EXTRA_MIN_S,
    STAGE_MARGIN_FRACTION,
    STAGE_MARGIN_MIN_S,
    STOPPED_STATES,
)

POLL_S = 0.1  # how often a moving stage's position is read


@dataclass
class StageMoveLogic(MovableLogic[float]):
    """A move through the API, followed until the stage stands."""

    connection: CamdConnection
    set_readback: Callable[[float], None]
    speed_m_s: SignalR[float]

    async def stop(self) -> None:
        await self.connection.request("POST", "/motion/stop")

    async def move(self, new_position: float, timeout: TimeoutCalculator) -> None:
        await self.setpoint.set(new_position)
        body: dict[str, object] = {"position_m": new_position, "wait": False}
        speed = await self.speed_m_s.get_value()
        if speed > 0:
            body["speed_m_s"] = speed
        doc = await self.connection.request("POST", "/motion/move", body)
        await follow_operation(
            self.connection, doc, self.set_readback, f"move to {new_position * 1e3:.3f} mm"
        )


async def follow_operation(
    connection: CamdConnection,
    doc: dict[str, Any],
    set_readback: Callable[[float], None],
    what: str,
) -> dict[str, Any]:
    """Follow the move or homing that answered ``doc`` until the stage stands, passing each
    position read to ``set_readback``; the last motion document. Bounded as the blocking
    client's ``wait_stage`` bounds it: the daemon's estimate, a margin, and as long again."""
    operation = doc["operation"]
    seq, expected = operation["seq"], operation["expected_duration_s"]
    margin = max(STAGE_MARGIN_MIN_S, STAGE_MARGIN_FRACTION * expected)
    deadline = time.monotonic() + expected + margin + max(STAGE_EXTRA_MIN_S, expected)
    while True:
        reading, now = doc["reading"], doc.get("operation")
        set_readback(reading["position_m"])
        where = f"the stage is {reading['state']} at {reading['position_m'] * 1e3:.3f} mm"
        if now is None or now["seq"] != seq:
            raise CamdError(
                f"the stage's {what} was taken over by another command ({where}); "
                "see `camctl events`",
                "stage_taken",
            )
        if not now["active"] and reading["state"] in STOPPED_STATES:
            return doc
        if time.monotonic() > deadline:
            raise CamdError(
                f"the stage's {what} has not ended after its estimated {expected:.3g} s and "
                f"the margin ({where}); it was not stopped: `camctl stage stop` stops it",
                "timeout",
            )
        await asyncio.sleep(POLL_S)
        doc = await connection.get("/motion")


class CamdStage(StandardReadable, StandardMovable[float]):
    """The scan stage of the daemon behind ``connection``: position in metres from home.

    ``speed_m_s`` (a setting, 0 = the stage's speed limit) is the speed of each move;
    ``readback`` and ``setpoint`` are the position read and the last position asked for.
    """

    def __init__(self, connection: CamdConnection, name: str = "") -> None:
        self.connection = connection
        self._enabled_here = False
        with self.add_children_as_readables(StandardReadableFormat.HINTED_SIGNAL):
            self.readback, self._set_readback = soft_signal_r_and_setter(
                float, 0.0, units="m", getter=self._position_m
            )
        with self.add_children_as_readables(StandardReadableFormat.CONFIG_SIGNAL):
            self.speed_m_s = soft_signal_rw(float, 0.0, units="m/s")
        self.setpoint = soft_signal_rw(float, 0.0, units="m")
        super().__init__(name=name)

    @cached_property
    def movable_logic(self) -> StageMoveLogic:
        return StageMoveLogic(
            setpoint=self.setpoint,
            readback=self.readback,
            connection=self.connection,
            set_readback=self._set_readback,
            speed_m_s=self.speed_m_s,
        )

    async def _position_m(self) -> float:
        doc = await self.connection.get("/motion")
        return float(doc["reading"]["position_m"])

    @AsyncStatus.wrap
    async def stage(self) -> None:
        """Take control, then energise the motor if it is released."""
        await self.connection.staged(holder_name(self), self._energise)

    @AsyncStatus.wrap
    async def unstage(self) -> None:
        """Release the motor if staging energised it, then give control back."""
        await self.connection.unstaged(holder_name(self), self._release)

    async def _energise(self) -> None:
        doc = await self.connection.get("/motion")
        self._enabled_here = doc["reading"]["state"] == "disabled"
        if self._enabled_here:
            await self.connection.request("POST", "/motion/enable", {"on": True})
        await self.setpoint.set(doc["reading"]["position_m"])

    async def _release(self) -> None:
        if self._enabled_here:
            self._enabled_here = False
            await self.connection.request("POST", "/motion/enable", {"on": False})

    @AsyncStatus.wrap
    async def home(self) -> None:
        """Find the home switch and zero the position there (POST /api/v1/motion/home),
        returning once homed."""
        doc = await self.connection.request("POST", "/motion/home", {"wait": False})
        doc = await follow_operation(self.connection, doc, self._set_readback, "homing")
        await self.setpoint.set(doc["reading"]["position_m"])
