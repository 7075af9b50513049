"""The service: device session, state machine, HTTP API, telemetry archive, systemd notify.

``camd serve`` (camd.daemon.serve) composes them; each module has one job and can be used and
tested alone.
"""
