"""The simulated camera only: its scene, noise seed, ideal stage and stage faults, reference
polariser, one-off command failures, and what it made (docs/simulator.md)."""

from __future__ import annotations

from typing import Any, Unpack, cast

from camd.client.connection import API, HttpClient
from camd.client_requests import (
    SimFailNextRequestOptions,
    SimStageFaultsRequestOptions,
    StageRequestOptions,
)
from camd.client_types import SimSettings, SimStageTruth, SimStreamStats, StageResponse


class SimClient(HttpClient):
    """The client of the simulated camera's routes (``/api/v1/sim``)."""

    def set_scene(self, spec: str) -> None:
        """Simulated camera only: the scene in front of it, e.g. ``"bars:lux=3"``."""
        self._request("PUT", f"{API}/sim/scene", json={"spec": spec})

    def set_sim_seed(self, seed: int) -> None:
        """Simulated camera only: restart its temporal noise and frame-fault random streams
        from ``seed`` (same seed, same following acquisitions; the fixed pattern is kept)."""
        self._request("PUT", f"{API}/sim/seed", json={"seed": seed})

    def set_stage(self, **options: Unpack[StageRequestOptions]) -> StageResponse:
        """Simulated camera only: track the synchronous speed (``track``, the default), or run
        at ``speed_m_s``."""
        return cast(StageResponse, self._json("PUT", f"{API}/sim/stage", json=options))

    def set_stage_faults(self, **faults: Unpack[SimStageFaultsRequestOptions]) -> None:
        """Simulated camera only: the stepper stage's imperfections (as --inject stage_*); those
        not given are none."""
        self._request("PUT", f"{API}/sim/stage/faults", json=faults)

    def stage_truth(self) -> SimStageTruth:
        """Simulated camera only: the stage's true position, velocity and missed steps."""
        return cast(SimStageTruth, self._json("GET", f"{API}/sim/stage/truth"))

    def set_polarizer(self, angle_deg: float | None) -> None:
        """Simulated camera only: the reference polariser's axis in degrees (None: out)."""
        self._request("PUT", f"{API}/sim/polarizer", json={"angle_deg": angle_deg})

    def fail_next(self, command: str, **how: Unpack[SimFailNextRequestOptions]) -> None:
        """Simulated camera only: make the (skip + 1)-th next ``command`` (e.g.
        "REG_WRITE_BURST") fail, refused with a NAK of ``error`` (e.g. "BUSY"), lost because
        the camera drops off the line for ``duration_s``, or (START_STREAM, WHEEL_ACQUIRE)
        executed with the stream it starts ended by the camera after ``end_after_frames``
        frames; give one of the three."""
        body: dict[str, Any] = {"command": command, **how}
        self._request("POST", f"{API}/sim/fail-next", json=body)

    def clear_fail_next(self) -> None:
        """Simulated camera only: disarm a failure armed with ``fail_next``."""
        self._request("DELETE", f"{API}/sim/fail-next")

    def sim_settings(self) -> SimSettings:
        """What the daemon last set on the simulated camera (scene, ideal stage, polariser,
        stage faults), so that it can be put back; ``available`` is false on hardware."""
        return cast(SimSettings, self._json("GET", f"{API}/sim"))

    def sim_stream_stats(self) -> SimStreamStats:
        """Simulated camera only: what its stream engine made, sent and injected."""
        return cast(SimStreamStats, self._json("GET", f"{API}/sim/stream"))
