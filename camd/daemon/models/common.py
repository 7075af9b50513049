"""What every API body shares: requests' strictness (unknown keys, booleans for integers,
NaN and subnormal numbers refused), the error body, the imaging mode.

Requests forbid unknown keys so that a typo is a 400 naming the key rather than a silently
ignored parameter.
"""

from __future__ import annotations

import math
import sys
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from camd.daemon.config_sections import CompressionLevel, CompressionName
from camd.store.compression import FILTERS

Mode = Literal["area", "tdi"]


FLOAT_NORMAL_MIN = sys.float_info.min
"""The smallest magnitude a request's number may have besides 0 (2.2e-308): below it a float
is subnormal, and what it is turned into (a period from a speed, a rate, a register count)
overflows or loses its precision."""


def _numbers(value: object) -> list[float]:
    """The floats in a field's value, entries of lists and objects included."""
    if isinstance(value, float):
        return [value]
    if isinstance(value, list | tuple):
        return [x for item in value for x in _numbers(item)]
    if isinstance(value, dict):
        return [x for item in value.values() for x in _numbers(item)]
    return []  # a nested request model checks its own fields


class _Request(BaseModel):
    # Strict: a boolean is not an integer and "3" is not a number (a JSON integer is still a
    # number); NaN and infinities are refused. 400 messages give each field's valid values
    # (camd.daemon.api_validation.valid_values), read from its own type and constraints.
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False)

    @field_validator("*", mode="after")
    @classmethod
    def _no_subnormal_numbers(cls, value: Any) -> Any:
        """Every number of every request is 0 or normal: one check for all fields (a speed of
        5e-324 passed "more than 0" and turned into an infinite line period, a 500)."""
        for number in _numbers(value):
            if number != 0.0 and math.isfinite(number) and abs(number) < FLOAT_NORMAL_MIN:
                raise ValueError(
                    f"{number!r} is too small to compute with: a subnormal number, below "
                    f"{FLOAT_NORMAL_MIN:.3g}; give 0 where 0 is allowed, or a value in range"
                )
        return value


class _Compressed(_Request):
    """A request that writes a file: how the file is compressed, if not as the config says."""

    compression: CompressionName | None = Field(
        default=None,
        description="compress the file's frames (lines) with this lossless filter, or off: one "
        f"of {', '.join(FILTERS)} (docs/stream.md, Compression); null = the config's "
        "store.compression",
    )
    compression_level: CompressionLevel = Field(
        default=None,
        description="the filter's level, for filters that have levels (with compression); "
        "null = the filter's default",
    )


class ErrorResponse(BaseModel):
    """The body of every error response."""

    error: str = Field(description="what went wrong and what to change")
    code: str = Field(
        description="what kind of error, for programs: each response status of each route "
        "lists the codes it may carry (docs/api.md, Errors, says what each means)"
    )
