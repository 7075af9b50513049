"""The filter wheel as a settable ophyd-async device: its speed in deg/s (docs/wheel.md).

``set(w)`` turns the wheel at ``w`` deg/s (0 stops it; PUT /api/v1/wheel/speed, which the
daemon allows only while nothing acquires) and completes once the daemon has answered. Its
readings (``speed_deg_s``, hinted; ``angle_deg``; ``channel``, -1 between light windows) are
read from GET /api/v1/wheel when read. Staged, it holds the connection's control lease.
"""

from __future__ import annotations

from ophyd_async.core import (
    AsyncStatus,
    StandardReadable,
    StandardReadableFormat,
    soft_signal_r_and_setter,
    soft_signal_rw,
)

from camd.bluesky.connection import CamdConnection, holder_name

NO_CHANNEL = -1  # the channel reading between two light windows


class CamdFilterWheel(StandardReadable):
    """The filter wheel of the daemon behind ``connection``."""

    def __init__(self, connection: CamdConnection, name: str = "") -> None:
        self.connection = connection
        with self.add_children_as_readables(StandardReadableFormat.HINTED_SIGNAL):
            self.speed_deg_s = soft_signal_rw(
                float, 0.0, units="deg/s", getter=self._speed, setter=self._set_speed
            )
        with self.add_children_as_readables():
            self.angle_deg, _ = soft_signal_r_and_setter(float, units="deg", getter=self._angle)
            self.channel, _ = soft_signal_r_and_setter(int, getter=self._channel)
        super().__init__(name=name)

    @AsyncStatus.wrap
    async def set(self, value: float) -> None:
        """Turn the wheel at ``value`` deg/s (0 stops it)."""
        await self.speed_deg_s.set(value)

    @AsyncStatus.wrap
    async def stage(self) -> None:
        await self.connection.hold_control(holder_name(self))

    @AsyncStatus.wrap
    async def unstage(self) -> None:
        await self.connection.release_control(holder_name(self))

    async def _set_speed(self, value: float | None) -> float:
        body = {"speed_deg_s": 0.0 if value is None else value}
        doc = await self.connection.request("PUT", "/wheel/speed", body)
        return float(doc["speed_deg_s"])

    async def _speed(self) -> float:
        return float((await self.connection.get("/wheel"))["speed_deg_s"])

    async def _angle(self) -> float:
        return float((await self.connection.get("/wheel"))["angle_deg"])

    async def _channel(self) -> int:
        channel = (await self.connection.get("/wheel"))["channel"]
        return NO_CHANNEL if channel is None else int(channel)
