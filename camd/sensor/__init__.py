"""Sensor registers: maps as data, typed access through a bridge, the timing they set.

- ``camd.sensor.regmap``: register maps (``config/sensors/<sensor>.toml``), validated at load
  (their entries in ``regmap_entries``, the checks across entries in ``regmap_checks``)
- ``camd.sensor.registers.SensorRegisters``: validated, verified access by name or address
  (its writes planned by ``camd.sensor.write_plan``, pure)
- ``camd.sensor.timing_view``: ``SensorTiming`` from the registers (pure)
- ``camd.sensor.bridge.RegisterBridge``: how the host reaches the registers (FPGA, USB-SPI)

Names are imported lazily so that importing a pure submodule (``camd.sensor.regmap``, as the
simulated camera does) does not pull in the stateful ones.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from camd.sensor.bridge import BridgeError, RegisterBridge
    from camd.sensor.registers import (
        RegisterDiff,
        RegisterReading,
        SensorRegisters,
        VerifyError,
    )
    from camd.sensor.regmap import (
        RegisterAccessError,
        RegisterMap,
        RegisterMapError,
        RegisterValueError,
        list_sensors,
        load_register_map,
    )
    from camd.sensor.timing_view import SensorTiming, sensor_timing

_EXPORTS = {
    "BridgeError": "camd.sensor.bridge",
    "RegisterBridge": "camd.sensor.bridge",
    "RegisterAccessError": "camd.sensor.regmap",
    "RegisterMap": "camd.sensor.regmap",
    "RegisterMapError": "camd.sensor.regmap",
    "RegisterValueError": "camd.sensor.regmap",
    "list_sensors": "camd.sensor.regmap",
    "load_register_map": "camd.sensor.regmap",
    "RegisterDiff": "camd.sensor.registers",
    "RegisterReading": "camd.sensor.registers",
    "SensorRegisters": "camd.sensor.registers",
    "VerifyError": "camd.sensor.registers",
    "SensorTiming": "camd.sensor.timing_view",
    "sensor_timing": "camd.sensor.timing_view",
}

__all__ = [
    "BridgeError",
    "RegisterAccessError",
    "RegisterBridge",
    "RegisterDiff",
    "RegisterMap",
    "RegisterMapError",
    "RegisterReading",
    "RegisterValueError",
    "SensorRegisters",
    "SensorTiming",
    "VerifyError",
    "list_sensors",
    "load_register_map",
    "sensor_timing",
]


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'camd.sensor' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
