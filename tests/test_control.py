"""One controlling client at a time (camd.daemon.control), over HTTP and on its own.

Two clients of one daemon, "alice" and "bob" (the X-Camd-Client header, as CamdClient and
camctl send it): reading never needs control; changing the camera does; an acquisition belongs
to the client that started it; a forced takeover is logged; an emergency stop is never refused.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

import pytest

from camd.client import CamdClient, CamdError
from camd.daemon.acquisition import AcquisitionSlot, acting_as
from camd.daemon.control import Control
from camd.daemon.errors import NotInControl
from tests.test_camctl import camctl, camctl_json
from tests.test_trust import small_window_daemon

# Not ``exclusive``: who may change what, and what a refusal says; the one scan runs at the
# window's own rate until stopped, and nothing is asked of its frames. Checked beside
# `stress-ng --cpu 2`.


@pytest.fixture(scope="module")
def url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    with small_window_daemon(tmp_path_factory.mktemp("camd-control")) as url:
        yield url


@pytest.fixture
def clients(url: str) -> Iterator[tuple[CamdClient, CamdClient]]:
    with CamdClient(url, client="alice") as alice, CamdClient(url, client="bob") as bob:
        yield alice, bob
        for who in (alice, bob):
            who.release_control()


def refused(call: object) -> CamdError:
    with pytest.raises(CamdError) as info:
        call()  # type: ignore[operator]
    assert info.value.code == "not_in_control", info.value.message
    assert info.value.http_status == 423
    return info.value


def test_observers_read_everything_while_another_client_holds_control(
    clients: tuple[CamdClient, CamdClient],
) -> None:
    alice, bob = clients
    taken = alice.take_control(30)
    assert taken["holder"] == "alice" and taken["why"] == "lease" and taken["you"] == "alice"
    status = bob.status()
    assert status["control"]["holder"] == "alice" and status["control"]["you"] == "bob"
    # Every read answers bob.
    bob.telemetry()
    bob.events()
    bob.registers()
    bob.timing()
    bob.scan()
    bob.stream()
    bob.motion()
    bob.wheel()
    bob.link()
    assert bob.control()["holder"] == "alice"
    assert "camd_state" in bob.metrics()
    # Changing anything is refused, naming the holder and how to take over.
    error = refused(lambda: bob.set_mode("tdi"))
    assert error.message.startswith("cannot change the imaging mode: alice holds control since")
    assert "(lease, lease until" in error.message
    assert "you (bob) may read but not change the camera" in error.message
    assert "`camctl control take --force`" in error.message
    for call in (
        lambda: bob.write_registers({"EXPOSURE": 3}),
        lambda: bob.start_stream(0),
        lambda: bob.stop_scan(),
        lambda: bob.set_scene("flat"),
        lambda: bob.move_stage(0.1),
        lambda: bob.set_wheel_speed(10.0),
        lambda: bob.take_control(30),
    ):
        refused(call)
    # The holder may; once it gives control back, anyone may.
    assert alice.set_mode("area")["mode"] == "area"
    assert alice.release_control()["holder"] is None
    assert bob.set_mode("area")["mode"] == "area"


def test_a_scan_belongs_to_its_client_until_a_forced_takeover(
    clients: tuple[CamdClient, CamdClient], tmp_path: Path
) -> None:
    alice, bob = clients
    scan = alice.start_scan(4, 0, out=str(tmp_path / "alice.h5"), drive_stage=False)
    try:
        holder = bob.control()
        assert holder["holder"] == "alice" and holder["why"] == "a scan it started is running"
        assert holder["expires_t_s"] is None
        error = refused(bob.stop_scan)
        assert error.message.startswith("cannot stop the scan: alice holds control")
        assert bob.scan()["state"] == "running"
        taken = bob.take_control(30, force=True)
        assert taken["holder"] == "bob"
        messages = [e["message"] for e in bob.events(limit=20)["events"]]
        assert "control taken over by bob from alice (a scan it started is running)" in messages
        refused(alice.stop_scan)  # alice lost it
        stopped = bob.stop_scan()
        assert stopped["state"] == "stopped" and stopped["file"] == scan["file"]
    finally:
        for who in (alice, bob):
            with contextlib.suppress(CamdError):
                who.stop_scan()


def test_an_emergency_stop_is_never_refused(clients: tuple[CamdClient, CamdClient]) -> None:
    alice, bob = clients
    alice.take_control(30)
    alice.enable_stage(True)
    alice.run_stage(0.002)
    stop = bob.estop()  # bob does not hold control
    assert "stage" in stop["stopped"] and stop["failed"] == []
    assert bob.motion()["reading"]["state"] == "estop"
    assert any(
        e["message"].startswith("EMERGENCY STOP by bob: stopped stage")
        for e in bob.events(limit=20)["events"]
    )
    # It latched: nothing moves until someone with control releases it; bob does not hold it.
    with pytest.raises(CamdError) as latched:
        alice.enable_stage(True)
    assert latched.value.code == "estop_latched" and latched.value.http_status == 409
    assert "`camctl estop release`" in latched.value.message
    refused(bob.release_estop)
    assert alice.release_estop()["released_by"] == "alice"
    alice.enable_stage(True)  # clears the stage's own emergency stop
    assert alice.motion()["reading"]["state"] == "idle"


def test_camctl_control_commands(url: str) -> None:
    taken = camctl_json(url, "--client", "carol", "control", "take", "--ttl-s", "30")
    assert taken["holder"] == "carol" and taken["you"] == "carol"
    proc = camctl(url, "--client", "dave", "mode", "tdi")
    assert proc.returncode == 1
    assert "cannot change the imaging mode: carol holds control" in proc.stderr
    shown = camctl(url, "--client", "dave", "control")
    assert shown.returncode == 0 and "carol" in shown.stdout
    assert camctl_json(url, "--client", "carol", "control", "release")["holder"] is None


# -- the control rules on their own (an injected clock instead of waiting) ------------------


def test_leases_expire_renew_and_pin_to_an_acquisition() -> None:
    now = [1000.0]
    events: list[tuple[str, str, str]] = []
    slot = AcquisitionSlot()
    control = Control(slot, lambda *e: events.append(e), clock=lambda: now[0])
    control.take("alice", 10.0)
    with pytest.raises(NotInControl, match=r"alice holds control since .* \(lease\)"):
        control.take("bob", 10.0)
    now[0] += 9.0
    control.take("alice", 10.0)  # renewed: until 1019
    assert control.holder() is not None and control.holder().expires_t_s == 1019.0  # type: ignore[union-attr]
    now[0] += 10.5
    assert control.holder() is None  # expired
    assert ("info", "control", "control lease of alice expired; control is free") in events
    control.check("bob", "change the mode")  # free: anyone
    with acting_as("bob"):
        scan = slot.claim("scan", "M = 4, until stopped to /x.h5")
    holder = control.holder()
    assert holder is not None and holder.client == "bob" and holder.expires_t_s is None
    with pytest.raises(
        NotInControl, match=r"bob holds control since .* \(a scan it started is running\)"
    ):
        control.check("alice", "stop the scan")
    slot.release(scan)
    control.check("alice", "stop the scan")


def test_the_lease_events_say_what_is_true() -> None:
    """A lease that expires (or is revoked) while its client's acquisition runs leaves that
    client in control: the event says so, not "control is free"."""
    now = [1000.0]
    events: list[tuple[str, str, str]] = []
    slot = AcquisitionSlot()
    control = Control(slot, lambda *e: events.append(e), clock=lambda: now[0])
    control.take("carol", 10.0)
    with acting_as("carol"):
        stare = slot.claim("stare", "300 frames")
    now[0] += 11.0
    holder = control.holder()
    assert holder is not None and holder.client == "carol" and holder.expires_t_s is None
    assert (
        "info",
        "control",
        "control lease of carol expired; carol still holds control while the stare it started runs",
    ) in events
    slot.release(stare)
    assert control.holder() is None


def test_revoke_ends_a_lease_with_its_holders_life() -> None:
    events: list[tuple[str, str, str]] = []
    control = Control(AcquisitionSlot(), lambda *e: events.append(e))
    control.take("campaign-job-3", 60.0)
    control.set_activity("campaign-job-3", "step 2/8")
    control.revoke("someone-else", "not the holder")  # harmless
    assert control.holder() is not None and control.activity() is not None
    control.revoke("campaign-job-3", "its worker exited with status -9")
    assert control.holder() is None and control.activity() is None
    assert events[-1] == (
        "info",
        "control",
        "control of campaign-job-3 ended (its worker exited with status -9); control is free",
    )
