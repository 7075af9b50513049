"""The image sensor: its registers (read, write, compare, whole configurations), the timing they
set, and the training of its LVDS link (docs/sensors.md)."""

from __future__ import annotations

from typing import Any, cast

from camd.client.connection import API, HttpClient
from camd.client_types import (
    RegisterConfig,
    RegisterDiffResponse,
    RegisterReading,
    RegistersResponse,
    RegisterWriteResponse,
    TimingResponse,
    TrainResponse,
)


class SensorClient(HttpClient):
    """The client of the sensor routes."""

    def registers(self) -> RegistersResponse:
        """Every sensor register, in address order."""
        return cast(RegistersResponse, self._json("GET", f"{API}/registers"))

    def read_register(self, key: str | int) -> RegisterReading:
        """One register by name or address."""
        return cast(RegisterReading, self._json("GET", f"{API}/registers/{key}"))

    def write_registers(self, values: dict[str, int | str]) -> RegisterWriteResponse:
        """Write registers by name (REG, REG.field, GROUP); all or nothing, verified."""
        return cast(
            RegisterWriteResponse, self._json("POST", f"{API}/registers", json={"values": values})
        )

    def diff_registers(self, values: dict[str, int] | None = None) -> RegisterDiffResponse:
        """Registers differing from their reset values, or from ``values`` when given."""
        body: dict[str, Any] = (
            {"against": "reset"} if values is None else {"against": "values", "values": values}
        )
        return cast(RegisterDiffResponse, self._json("POST", f"{API}/registers/diff", json=body))

    def register_config(self) -> RegisterConfig:
        """The whole configuration (RW and WO non-volatile registers)."""
        return cast(RegisterConfig, self._json("GET", f"{API}/registers/config"))

    def load_register_config(self, config: RegisterConfig) -> RegisterWriteResponse:
        """Write a whole configuration (refused whole if invalid or for another sensor)."""
        return cast(
            RegisterWriteResponse, self._json("PUT", f"{API}/registers/config", json=dict(config))
        )

    def timing(self) -> TimingResponse:
        """The timing the sensor's registers set."""
        return cast(TimingResponse, self._json("GET", f"{API}/timing"))

    def train(self) -> TrainResponse:
        """Train the sensor's LVDS link now."""
        return cast(TrainResponse, self._json("POST", f"{API}/train"))

    def last_training(self) -> TrainResponse:
        """The last training result."""
        return cast(TrainResponse, self._json("GET", f"{API}/train"))
