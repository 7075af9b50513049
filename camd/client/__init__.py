"""A small typed client of the camd HTTP API (docs/api.md), for camctl and for any script.

Every method returns the API's JSON document as a plain dict, typed with the TypedDicts of
``camd.client_types``: those are generated from the API's pydantic models
(camd/daemon/models/) by ``python -m camd.daemon.client_types_gen``, so they name exactly the
keys the daemon sends, and are named after the models (``StatusResponse``, ``ScanResponse``, ...).
A request's optional keys are typed by ``camd.client_requests``, generated from the same models:
only the keys given are sent, so that each default is the daemon's model's.
Failures raise ``CamdError`` built from the API's ``{"error", "code"}`` body, or
``DaemonUnreachable`` when nothing answers at the URL::

    from camd.client import CamdClient, CamdError

    with CamdClient() as cam:                   # $CAMD_URL or http://127.0.0.1:8422
        print(cam.status()["state"])
        result = cam.ping(count=100)
        print(result["rtt_ms"]["p99"])

The client is one class per resource, as the API has one router per resource: ``connection``
(the connection, the errors, ``UNSET``), ``device`` (status, link, telemetry, emergency stop),
``control``, ``sensor``, ``stream`` (and the live view's background, ROIs and lines), ``scan``,
``motion``, ``wheel``, ``sim`` and ``campaigns``; ``CamdClient`` has them all.
"""

from __future__ import annotations

from camd.client.campaigns import CampaignsClient
from camd.client.connection import (
    DEFAULT_URL,
    UNSET,
    CamdError,
    DaemonUnreachable,
    HttpClient,
    Unset,
    default_client_name,
    normalise_url,
)
from camd.client.control import ControlClient
from camd.client.device import DeviceClient
from camd.client.motion import MotionClient, StageProgress
from camd.client.scan import ScanClient
from camd.client.sensor import SensorClient
from camd.client.sim import SimClient
from camd.client.stream import StreamClient
from camd.client.wheel import WheelClient

__all__ = [
    "DEFAULT_URL",
    "UNSET",
    "CamdClient",
    "CamdError",
    "DaemonUnreachable",
    "HttpClient",
    "StageProgress",
    "Unset",
    "default_client_name",
    "normalise_url",
]


class CamdClient(
    DeviceClient,
    ControlClient,
    SensorClient,
    StreamClient,
    ScanClient,
    MotionClient,
    WheelClient,
    SimClient,
    CampaignsClient,
):
    """Client of one camd daemon.

    ``url`` defaults to ``$CAMD_URL``, else ``http://127.0.0.1:8422``; ``token`` to
    ``$CAMD_TOKEN`` (sent as ``Authorization: Bearer``). ``timeout_s`` bounds each request,
    except that ``ping`` extends it with the number of pings. ``client`` is the name the daemon
    knows this client by for control (``X-Camd-Client``): ``$CAMD_CLIENT``, else ``user@host``.
    """
