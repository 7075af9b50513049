"""The HTTP API's routes (docs/api.md), one ``APIRouter`` per resource; ``camd.daemon.api``
assembles them. Each module reaches the session and the requesting client through the
dependencies of ``deps``; a route that changes the camera declares ``needs_control``, which
checks control once and runs the route as the requesting client.
"""
