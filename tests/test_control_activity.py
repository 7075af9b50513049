"""What the controlling client says it is doing (PUT /api/v1/control/activity), for observers.

On its own (``camd.daemon.control.Control`` with an injected clock): only the holder may say
it, and it goes when control is given back, expires, ends with an acquisition or is taken over.
Over a real daemon (simulated camera, HTTP on loopback, clients "alice" and "bob"): it shows in
GET /control and GET /status; an observer is refused 423, a client while nobody holds control
409; bad bodies are 400s. A campaign run says each step as it goes, and an observer sees it.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from camd.campaign.loading import load_campaign
from camd.campaign.runner import CampaignRunner
from camd.client import CamdClient, CamdError
from camd.client_types import ControlInfo
from camd.daemon.acquisition import AcquisitionSlot, acting_as
from camd.daemon.control import Control
from camd.daemon.errors import NoControl, NotInControl
from camd.paths import config_dir
from tests.test_camctl import camctl
from tests.test_trust import small_window_daemon

# Not ``exclusive``: what is said and who sees it; the campaign's frames are the simulator's
# seeded ones whenever they arrive, and nothing is asked of their timing. Checked beside
# `stress-ng --cpu 2`.

EXAMPLE = config_dir() / "campaigns" / "example_stare.yaml"


# -- the rules on their own -------------------------------------------------------------------


def test_only_the_holder_says_and_it_goes_with_control() -> None:
    now = [1000.0]
    slot = AcquisitionSlot()
    control = Control(slot, lambda *e: None, clock=lambda: now[0])
    with pytest.raises(NoControl, match="nobody holds control; take it first"):
        control.set_activity("alice", "idle chatter")
    control.take("alice", 10.0)
    with pytest.raises(NotInControl, match="cannot set the activity: alice holds control"):
        control.set_activity("bob", "hijack")
    said = control.set_activity("alice", "campaign x: step 1/3", 0, 3)
    assert (said.client, said.text, said.done, said.total, said.t_s) == (
        "alice", "campaign x: step 1/3", 0, 3, 1000.0,
    )  # fmt: skip
    control.take("alice", 10.0)  # a renewal keeps it
    assert control.activity() == said
    control.release("bob")  # someone else's release: nothing
    assert control.activity() == said
    control.release("alice")
    assert control.activity() is None
    # Expiry.
    control.take("alice", 10.0)
    control.set_activity("alice", "step 2/3", 1, 3)
    now[0] += 11.0
    assert control.activity() is None and control.holder() is None
    # Takeover.
    control.take("alice", 10.0)
    control.set_activity("alice", "step 3/3", 2, 3)
    control.take("bob", 10.0, force=True)
    assert control.activity() is None
    control.release("bob")
    # Holding control through a running acquisition: said until it ends.
    with acting_as("bob"):
        scan = slot.claim("scan", "M = 4")
    control.set_activity("bob", "watching the scan")
    assert control.activity() is not None
    slot.release(scan)
    assert control.activity() is None


# -- over a daemon ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    with small_window_daemon(tmp_path_factory.mktemp("camd-activity")) as url:
        yield url


@pytest.fixture
def clients(url: str) -> Iterator[tuple[CamdClient, CamdClient]]:
    with CamdClient(url, client="alice") as alice, CamdClient(url, client="bob") as bob:
        yield alice, bob
        for who in (alice, bob):
            who.release_control()


def test_set_read_by_observers_and_cleared_on_release(
    clients: tuple[CamdClient, CamdClient],
) -> None:
    alice, bob = clients
    with pytest.raises(CamdError) as info:
        alice.set_activity("before taking control")
    assert (info.value.code, info.value.http_status) == ("no_control", 409)
    assert "nobody holds control; take it first (POST /api/v1/control" in info.value.message
    assert alice.control()["activity"] is None
    alice.take_control(30)
    doc = alice.set_activity("campaign mtf: step 3/12 acquire scan_m8", done=2, total=12)
    activity = doc["activity"]
    assert activity is not None
    assert (activity["text"], activity["done"], activity["total"]) == (
        "campaign mtf: step 3/12 acquire scan_m8", 2, 12,
    )  # fmt: skip
    assert activity["t_s"] > 0 and doc["holder"] == "alice"
    assert bob.control()["activity"] == activity
    assert bob.status()["control"]["activity"] == activity
    # An observer may read it, not say it.
    with pytest.raises(CamdError) as info:
        bob.set_activity("me too")
    assert (info.value.code, info.value.http_status) == ("not_in_control", 423)
    assert info.value.message.startswith("cannot set the activity: alice holds control since")
    assert bob.control()["activity"] == activity
    shown = camctl(alice.url, "--client", "bob", "control")
    assert shown.returncode == 0, shown.stderr
    assert "doing: campaign mtf: step 3/12 acquire scan_m8 (2/12)" in " ".join(shown.stdout.split())
    # Without done and total.
    plain = alice.set_activity("focusing")["activity"]
    assert plain is not None and (plain["text"], plain["done"], plain["total"]) == (
        "focusing", None, None,
    )  # fmt: skip
    assert alice.release_control()["activity"] is None
    assert bob.control()["activity"] is None


def test_a_takeover_clears_it(clients: tuple[CamdClient, CamdClient]) -> None:
    alice, bob = clients
    alice.take_control(30)
    alice.set_activity("long job", 1, 5)
    taken = bob.take_control(30, force=True)
    assert taken["holder"] == "bob" and taken["activity"] is None
    assert alice.control()["activity"] is None


@pytest.mark.parametrize(
    ("body", "words"),
    [
        (
            {"text": "a", "done": 3, "total": 2},
            "total: 2 is not valid (done = 3 is more than total = 2); use null or an integer >= 0",
        ),
        ({"text": "two\nlines"}, "text: 'two\\nlines' is not valid (text must be printable"),
        ({"text": "x" * 201}, "is not valid; use a string of 1 to 200 characters (printable"),
        ({"text": ""}, "text: '' is not valid; use a string of 1 to 200 characters"),
        ({"text": "a", "done": -1}, "done: -1 is out of range; use null or an integer >= 0"),
        ({"text": "a", "step": 1}, "step: unknown parameter"),
    ],
)
def test_bad_bodies_are_refused_naming_the_field(
    url: str, body: dict[str, Any], words: str
) -> None:
    headers = {"X-Camd-Client": "alice"}
    with httpx.Client(base_url=url, timeout=30, headers=headers) as http:
        http.post("/api/v1/control", json={"ttl_s": 30})
        try:
            answer = http.put("/api/v1/control/activity", json=body)
        finally:
            http.delete("/api/v1/control")
    assert answer.status_code == 400, answer.text
    assert answer.json()["code"] == "bad_request"
    assert words in answer.json()["error"]


class Recording(CamdClient):
    """A CamdClient that keeps what the runner said and what the daemon answered."""

    def __init__(self, url: str) -> None:
        super().__init__(url, timeout_s=120, client="runner")
        self.said: list[tuple[str, int | None, int | None, ControlInfo]] = []

    def set_activity(
        self, text: str, done: int | None = None, total: int | None = None
    ) -> ControlInfo:
        doc = super().set_activity(text, done, total)
        self.said.append((text, done, total, doc))
        return doc


def test_a_campaign_says_each_step_and_an_observer_sees_it(url: str, tmp_path: Path) -> None:
    spec = load_campaign(EXAMPLE)
    seen: list[ControlInfo] = []
    stop = threading.Event()

    def observe() -> None:
        with CamdClient(url, client="observer") as observer:
            while not stop.wait(0.05):
                seen.append(observer.control())

    watcher = threading.Thread(target=observe)
    client = Recording(url)
    watcher.start()
    try:
        outcome = CampaignRunner(client, spec, tmp_path / "run", quick=True).run(report=False)
    finally:
        stop.set()
        watcher.join(10)
        after = client.control()
        client.close()
    assert outcome.passed
    said = client.said
    # example_stare --quick: window, dark_scene, dark, dark_noise, then 2 x (scene, stare,
    # stats, psnr_ok): 12 step instances, then the settings put back.
    steps = [
        ("configure", "window"), ("configure", "dark_scene"), ("acquire", "dark"),
        ("measure", "dark_noise"),
        *[(kind, f"light[{i}]/{name}") for i in range(2) for kind, name in (
            ("configure", "scene"), ("acquire", "stare"), ("measure", "stats"),
            ("check", "psnr_ok"),
        )],
    ]  # fmt: skip
    n = len(steps)
    expected = [
        (f"campaign example_stare: step {i}/{n} {kind} {key}", i - 1, n)
        for i, (kind, key) in enumerate(steps, start=1)
    ]
    expected.append(("campaign example_stare: putting the daemon's settings back", n, n))
    assert [(text, done, total) for text, done, total, _ in said] == expected
    for text, done, _, doc in said:  # the daemon took each one
        assert doc["holder"] == "runner" and doc["activity"] is not None
        assert (doc["activity"]["text"], doc["activity"]["done"]) == (text, done)
    # An observer saw the steps go by, under the runner's control; once it gave control back,
    # nothing is said.
    watched = [doc["activity"]["text"] for doc in seen if doc["activity"] is not None]
    assert watched and set(watched) <= {text for text, _, _ in expected}
    assert all(doc["holder"] == "runner" for doc in seen if doc["activity"] is not None)
    assert after["holder"] is None and after["activity"] is None
