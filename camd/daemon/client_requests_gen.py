"""Generate camd/client_requests.py: the optional keys of the API's request bodies as TypedDicts,
typing the keyword arguments of ``CamdClient``'s methods.

A request model's optional fields carry their defaults (``camd.daemon.models``). A client method
takes them as ``**options: Unpack[ScanRequestOptions]`` and sends only the keys it is given, so
that the daemon's model supplies the others: each default is written once, in the model (the
generated comments quote it), and the client's keyword arguments are the model's fields, of the
model's types. ``tests/test_client_requests.py`` fails when the committed file is stale, and
checks each method of ``CLIENT_REQUESTS`` against its model.

``CLIENT_REQUESTS`` says how ``CamdClient``'s methods send each request model: the optional keys
a method takes as parameters of its own (``own``: those its callers pass positionally, such as
``ping(5)``'s count, whose default ``UNSET`` means "not sent", and those the client converts or
that hold a model), the keys it never sends (``not_taken``), and the rest, its keyword options.
One TypedDict per entry with options left, named ``<Model>Options`` unless the entry names it,
``total=False``, with those fields in field order, each keyed by the name the API reads (its
alias, else its name). The types are rendered as camd/client_types.py renders them
(``camd.daemon.client_types_gen``); a field holding a model is refused (take it as ``own``).

    python -m camd.daemon.client_requests_gen            write camd/client_requests.py
    python -m camd.daemon.client_requests_gen --check    exit 1 if the file differs from the render
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from pydantic import BaseModel
from pydantic.fields import FieldInfo

from camd.daemon.client_types_gen import (
    ClientTypesError,
    comment_lines,
    docstring_lines,
    field_lines,
    generator_main,
    is_request,
    module_text,
    nested_models,
    render_type,
    summary,
)
from camd.daemon.models import (
    ActivityRequest,
    BackgroundRequest,
    CampaignActionRequest,
    CampaignStartRequest,
    ControlRequest,
    LinkCommandRequest,
    MotionEnableRequest,
    MotionMoveRequest,
    PingRequest,
    ScanRequest,
    SimFailNextRequest,
    SimStageFaultsRequest,
    StageRequest,
    StreamStartRequest,
    WheelAcquireRequest,
)

COMMAND = "python -m camd.daemon.client_requests_gen"
OUTPUT = Path(__file__).resolve().parents[1] / "client_requests.py"


@dataclass(frozen=True)
class ClientRequest:
    """How ``CamdClient``'s ``methods`` send ``model``: its optional keys but ``own`` (parameters
    of the methods' own, default ``UNSET``: not sent) and ``not_taken`` (never sent) are their
    keyword options, the TypedDict ``name`` (default ``<Model>Options``)."""

    model: type[BaseModel]
    methods: tuple[str, ...]
    own: tuple[str, ...] = ()
    not_taken: tuple[str, ...] = ()
    name: str = ""

    @property
    def options_name(self) -> str:
        """The name of the TypedDict of the methods' keyword options."""
        return self.name or f"{self.model.__name__}Options"

    def options(self) -> list[tuple[str, FieldInfo]]:
        """(key, field) of the optional fields the methods take as keyword options."""
        fields = optional_fields(self.model)
        keys = {key for key, _ in fields}
        unknown = sorted((set(self.own) | set(self.not_taken)) - keys)
        if unknown:
            raise ClientTypesError(
                f"{self.model.__name__} has no optional key {', '.join(unknown)}"
            )
        return [(k, f) for k, f in fields if k not in self.own and k not in self.not_taken]


# Every client method that sends a request model with defaults, and how.
CLIENT_REQUESTS: tuple[ClientRequest, ...] = (
    ClientRequest(ScanRequest, ("start_scan",)),
    ClientRequest(PingRequest, ("ping",), own=("count",)),
    # payload_hex: the method takes the payload as bytes (``payload``) and sends it as hex.
    ClientRequest(LinkCommandRequest, ("link_command",), own=("command", "payload_hex")),
    # timeout_s bounds an acquisition only: a started stream runs until stopped.
    ClientRequest(StreamStartRequest, ("start_stream",), own=("frames",), not_taken=("timeout_s",)),
    ClientRequest(StreamStartRequest, ("acquire",), own=("frames",), name="StreamAcquireOptions"),
    ClientRequest(BackgroundRequest, ("capture_background",), own=("frames",)),
    ClientRequest(ControlRequest, ("take_control",), own=("ttl_s",)),
    ClientRequest(ActivityRequest, ("set_activity",), own=("done", "total")),
    ClientRequest(MotionEnableRequest, ("enable_stage",), own=("on",)),
    # wait: the client always asks for an answer at once and polls (``wait_stage``) itself.
    ClientRequest(MotionMoveRequest, ("move_stage",), not_taken=("wait",)),
    ClientRequest(StageRequest, ("set_stage",)),
    ClientRequest(SimStageFaultsRequest, ("set_stage_faults",)),
    ClientRequest(SimFailNextRequest, ("fail_next",)),
    ClientRequest(WheelAcquireRequest, ("wheel_acquire",), own=("region",)),
    ClientRequest(CampaignStartRequest, ("start_campaign",)),
    ClientRequest(CampaignActionRequest, ("pause_campaign", "abort_campaign")),
)

HEADER = f'''\
# Generated from camd/daemon/models/ by `{COMMAND}`: do not edit.
"""The optional keys of the camd HTTP API's request bodies as TypedDicts: the keyword arguments
of the ``camd.client.CamdClient`` methods that send them.

Generated by ``{COMMAND}`` from the request models of
camd/daemon/models/: to change one, change the model and run that command
(tests/test_client_requests.py fails while this file is stale). A method takes
``**options: Unpack[ScanRequestOptions]`` and sends only the keys it is given; the daemon's model
supplies the others, so each default is written once, in the model (the comments here quote it).
The keys a method takes as parameters of its own (e.g. ``ping``'s count) are not here.
The module imports nothing of camd.
"""

from __future__ import annotations
'''


def optional_fields(model: type[BaseModel]) -> list[tuple[str, FieldInfo]]:
    """(key, field) of each field of ``model`` that has a default, in field order; the key is
    the name the API reads (the field's alias, else its name)."""
    out = []
    for name, info in model.model_fields.items():
        if info.is_required():
            continue
        key = info.alias or name
        if not key.isidentifier():
            raise ClientTypesError(f"{model.__name__}: key {key!r} is not a Python identifier")
        out.append((key, info))
    return out


def render_options(request: ClientRequest, annotations: list[str] | None = None) -> list[str]:
    """The TypedDict of the keyword options of ``request``'s methods (none: no lines)."""
    model = request.model
    if not is_request(model):
        raise ClientTypesError(f"{model.__name__} is not a request body")
    fields = request.options()
    if not fields:
        return []
    methods = ", ".join(f"``{m}``" for m in request.methods)
    left_out = [*request.own, *request.not_taken]
    taken = (
        ""
        if not left_out
        else " but " + " and ".join(filter(None, [", ".join(left_out[:-1]), left_out[-1]]))
    )
    text = (
        f"The optional keys of ``{model.__name__}``{taken}, the keyword arguments of {methods}: "
        f"{summary(model)} A key not given is not sent: the daemon's model supplies its default."
    )
    lines = [f"class {request.options_name}(TypedDict, total=False):", *docstring_lines(text)]
    lines.append("")
    for key, info in fields:
        if any(True for _ in nested_models(info.annotation)):
            raise ClientTypesError(
                f"{model.__name__}.{key} holds a model, which an options TypedDict does not "
                "express; give the method a parameter of its own"
            )
        default = f"default {info.get_default(call_default_factory=True)!r}"
        lines += comment_lines(f"{info.description}; {default}" if info.description else default)
        rendered = render_type(info.annotation, f"{model.__name__}.{key}")
        if annotations is not None:
            annotations.append(rendered)
        lines += field_lines(key, rendered)
    return lines


def render_client_requests(requests: Sequence[ClientRequest] = CLIENT_REQUESTS) -> str:
    """The text of camd/client_requests.py for ``requests``."""
    annotations: list[str] = []
    classes = [lines for request in requests if (lines := render_options(request, annotations))]
    return module_text(HEADER, classes, annotations)


def main(argv: Sequence[str] | None = None) -> int:
    return generator_main(
        argv,
        command=COMMAND,
        description="Generate camd/client_requests.py (the optional keys of the API's request "
        "bodies, as the client's keyword arguments) from the pydantic models in "
        "camd/daemon/models/.",
        output=OUTPUT,
        render=render_client_requests,
    )


if __name__ == "__main__":
    raise SystemExit(main())
