"""The camera's LINK_TRAINED event when TRAIN's answer never came (camd/daemon/sensor_service.py).

Found under load: the daemon's training on connect gave up after its attempts ("TRAIN: no
answer from the device ... after 6 attempt(s)"), the camera then finished training and said so
(LINK_TRAINED: every lane locked, 0 bit errors), and the daemon went on refusing streams as
"LVDS link not trained yet" (tests/test_realtime.py, one fresh-clone run in four).
"""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

from camd.daemon.config import load_config
from camd.daemon.sensor_service import SensorService


class _Events:
    """What SensorService's event handling uses of the session: its config and its log."""

    def __init__(self) -> None:
        self.config = load_config()
        self.logged: list[tuple[str, str, str]] = []

    def log_event(self, level: str, source: str, message: str) -> None:
        self.logged.append((level, source, message))


def _service() -> tuple[SensorService, _Events]:
    events = _Events()
    return SensorService(events, make_bridge=SimpleNamespace), events  # type: ignore[arg-type]


def test_a_trained_event_without_trains_answer_marks_the_link_trained() -> None:
    sensor, events = _service()
    assert not sensor.trained and sensor.training_summary() == "LVDS link not trained yet"
    event: dict[str, Any] = {"locked": "yes", "bit_errors": 0}
    assert sensor.on_event("LINK_TRAINED", event)
    assert sensor.trained
    assert sensor.training_summary().startswith("LVDS link trained (the camera's LINK_TRAINED")
    assert "TRAIN's answer did not come, so `camctl train` measures its lanes" in (
        sensor.training_summary()
    )
    assert events.logged[-1][2].startswith("the camera finished LVDS training (LINK_TRAINED)")
    # Lost again: untrained, saying when.
    sensor.on_event("LINK_LOST", {})
    assert not sensor.trained
    assert sensor.training_summary().startswith("LVDS link not trained: it lost its training")


def test_an_event_of_a_training_that_failed_leaves_the_link_untrained() -> None:
    for event in ({"locked": "no", "bit_errors": 0}, {"locked": "yes", "bit_errors": 3}):
        sensor, _ = _service()
        sensor.on_event("LINK_TRAINED", event)
        assert not sensor.trained and sensor.training_summary() == "LVDS link not trained yet"
