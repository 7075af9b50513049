"""``Sourced``: a physical value of a data file with its provenance (a paper's section, or
why it was assumed)."""

from __future__ import annotations

from typing import Generic, TypeVar

from pydantic import BaseModel, ConfigDict, Field, model_validator

T = TypeVar("T")


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
