"""The physical values of the data files: ``Sourced``, a value with its provenance (a paper's
section, or why it was assumed); the bounds they share (``Positive``, ``NonNegative``,
``Count``); a model's key for one, with its unit kept for the docs (``physical``,
``unit_of``)."""

from __future__ import annotations

from typing import Annotated, Any, Generic, TypeVar

from pydantic import BaseModel, ConfigDict, Field, model_validator

T = TypeVar("T")

Positive = Annotated[float, Field(gt=0)]
NonNegative = Annotated[float, Field(ge=0)]
Count = Annotated[int, Field(ge=1)]


class Sourced(BaseModel, Generic[T]):
    """A value with its provenance: exactly one of ``source`` or ``assumed``."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    value: T = Field(description="the value, in the unit the key's name gives")
    source: str | None = Field(default=None, description="where the value comes from")
    assumed: str | None = Field(default=None, description="why the value was chosen")

    @model_validator(mode="after")
    def _one_provenance(self) -> Sourced[T]:
        given = [k for k in ("source", "assumed") if (getattr(self, k) or "").strip()]
        if len(given) != 1:
            what = "both" if len(given) == 2 else "neither"
            raise ValueError(
                "give exactly one of `source` (where the value comes from) or `assumed` "
                f"(why it was chosen), not {what}"
            )
        return self

    @property
    def provenance(self) -> str:
        """``source: ...`` or ``assumed: ...``, for docs and reports."""
        if self.source:
            return f"source: {self.source}"
        return f"assumed: {self.assumed}"

    @property
    def is_assumed(self) -> bool:
        return bool(self.assumed)


def physical(description: str, unit: str, default: Any = ...) -> Any:
    """A model's key that holds a physical value (required unless a ``default`` is given);
    its unit is kept for the docs (``unit_of``)."""
    return Field(default, description=description, json_schema_extra={"unit": unit})


def unit_of(model: type[BaseModel], key: str) -> str | None:
    """The unit of ``model``'s physical key ``key`` ("" for a label or a pure number), None
    for a key that is not a physical value."""
    extra = model.model_fields[key].json_schema_extra
    if isinstance(extra, dict):
        unit = extra.get("unit")
        return unit if isinstance(unit, str) else None
    return None
