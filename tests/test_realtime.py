"""Real-time scheduling of the threads the hardware waits on (camd/daemon/realtime.py).

The decision is tested as a pure function, then with the real system calls in processes that
may and may not have real time; the daemon is started the way systemd/camd.service starts it
(tests/realtime_support.py) and its report held against what the kernel says of its threads;
and under a CPU hog of normal priority its closed loop must stay `ok` with no frame lost.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import pytest

from camd.cli._daemon_proc import DaemonProcess, DaemonStartError
from camd.client import CamdClient
from camd.daemon.realtime import Decision, decide
from tests.realtime_support import (
    UNIT_GRANT,
    WARM_UP_AS_SHIPPED,
    as_the_unit,
    cpu_hog,
    thread_scheduling,
    unit_service,
    without_realtime,
)
from tests.test_camctl import NO_TOKEN, camctl

NOT_ALLOWED = (
    "real-time scheduling is not allowed: RLIMIT_RTPRIO is 0 and the process has no "
    "CAP_SYS_NICE (under systemd: LimitRTPRIO= in the unit, docs/config.md)"
)
T_LINE_S = 100 * 513 / 25e6  # 100 hr400 rows (tests/test_motion_stack.py)
DISTURBANCE = {"error": -0.005, "ripple": 0.01}  # a clock 0.5 % slow and 1 % speed ripple


# -- the decision, pure ---------------------------------------------------------------------------


def test_decide_asks_for_what_the_process_may_have() -> None:
    def ask(setting: str = "auto", **allowed: object) -> Decision:
        limits = {"rtprio_limit": 0, "nice_floor": 20, "cap_sys_nice": False} | allowed
        return decide(setting, 10, -5, **limits)  # type: ignore[arg-type]

    assert ask("off", cap_sys_nice=True) == Decision(None, None, 'daemon.realtime = "off"')
    assert ask(cap_sys_nice=True) == Decision(10, None, None)
    assert ask("required", rtprio_limit=20) == Decision(10, None, None)
    assert ask(rtprio_limit=10) == Decision(10, None, None)
    assert ask(rtprio_limit=4) == Decision(
        4,
        None,
        "RLIMIT_RTPRIO 4 is below daemon.rt_priority 10: priority 4 (raise LimitRTPRIO= in the "
        "unit)",
    )
    assert ask(nice_floor=-10) == Decision(None, -5, NOT_ALLOWED)
    assert ask(nice_floor=-5) == Decision(None, -5, NOT_ALLOWED)
    assert ask(nice_floor=0) == Decision(
        None,
        None,
        f"{NOT_ALLOWED}; nor nice -5: RLIMIT_NICE allows nice 0 at the lowest (Nice= or "
        "LimitNICE= in the unit)",
    )
    assert ask().why == (
        f"{NOT_ALLOWED}; nor nice -5: RLIMIT_NICE allows no nice below 20 (Nice= or LimitNICE= "
        "in the unit)"
    )


# -- the decision with the real system calls -------------------------------------------------------

APPLY = textwrap.dedent(
    """
    import json, sys, threading
    from camd.daemon.realtime import Decision, apply, process_decision

    def on_a_thread(decision):
        got = []
        thread = threading.Thread(target=lambda: got.append(apply(decision)))
        thread.start()
        thread.join()
        scheduling, why = got[0]
        return [scheduling.describe(), why]

    print(json.dumps({
        "auto": on_a_thread(process_decision("auto", 10, -5)),
        "rr": on_a_thread(Decision(10, None, None)),
        "nice": on_a_thread(Decision(None, -5, "asked")),
    }))
    """
)


def run_apply(wrapper: list[str]) -> dict[str, list[str | None]]:
    done = subprocess.run(
        [*wrapper, sys.executable, "-c", APPLY], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)  # type: ignore[no-any-return]


@pytest.mark.skipif(sys.platform != "linux", reason="Linux scheduling")
def test_a_process_that_may_have_real_time_gets_it() -> None:
    got = run_apply(as_the_unit())
    assert got["auto"] == ["SCHED_RR 10", None], UNIT_GRANT
    assert got["rr"] == ["SCHED_RR 10", None]
    nice = int(unit_service()["Nice"])
    # The unit's nice is already -5: asking for -5 changes nothing and is no failure.
    assert got["nice"] == [f"SCHED_OTHER nice {nice}", "asked"]


@pytest.mark.skipif(sys.platform != "linux", reason="Linux scheduling")
def test_a_process_that_may_not_falls_back_and_says_why() -> None:
    got = run_apply(without_realtime())
    assert got["auto"] == [
        "SCHED_OTHER nice 0",
        f"{NOT_ALLOWED}; nor nice -5: RLIMIT_NICE allows no nice below 20 (Nice= or LimitNICE= "
        "in the unit)",
    ]
    # Asked for anyway (a seccomp filter refuses the same way): the refusal is the reason.
    assert got["rr"] == [
        "SCHED_OTHER nice 0",
        "SCHED_RR 10 refused: Operation not permitted (is RestrictRealtime=yes set in the unit, "
        "or has the control group no real-time budget?)",
    ]
    assert got["nice"] == ["SCHED_OTHER nice 0", "asked; nice -5 refused: Permission denied"]


def test_the_unit_grants_real_time_and_its_filters_allow_it() -> None:
    service = unit_service()
    assert int(service["LimitRTPRIO"]) >= 10  # daemon.rt_priority as shipped
    assert int(service["Nice"]) < 0
    assert service["RestrictRealtime"] == "false"  # "true" forbids SCHED_RR by seccomp
    # The whole process real-time would include the threads that compute without blocking.
    assert "CPUSchedulingPolicy" not in service
    # @system-service includes @resources: sched_setscheduler and setpriority.
    assert service["SystemCallFilter"] == "@system-service"


# -- the daemon, started as the unit starts it ----------------------------------------------------


def start(
    tmp: Path, wrapper: list[str], config: str = "", *, warm_up: bool = False
) -> DaemonProcess:
    """A daemon under ``wrapper``; ``warm_up``: its first scan's work done at start, as shipped
    (tests/realtime_support.py), for a daemon that scans in real time."""
    tmp.mkdir(exist_ok=True)
    (tmp / "camd.toml").write_text(config)
    env = {**NO_TOKEN, **(WARM_UP_AS_SHIPPED if warm_up else {})}
    return DaemonProcess(
        tmp, extra_args=["--config", str(tmp / "camd.toml")], env=env, wrapper=wrapper
    )


@pytest.fixture(scope="module")
def unit_daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProcess]:
    with start(tmp_path_factory.mktemp("camd-rt"), as_the_unit(), warm_up=True) as daemon:
        with CamdClient(daemon.url, timeout_s=60) as client:
            client.wait_ready(60)
            client.set_scene("edge:angle_deg=5")
        yield daemon
    assert daemon.exit_code in (0, -15), daemon.log_path.read_text()


def test_the_daemon_reports_the_real_time_it_got(unit_daemon: DaemonProcess) -> None:
    with CamdClient(unit_daemon.url, timeout_s=60) as client:
        client.acquire(5)
        scheduling = client.status()["daemon"]["scheduling"]
    assert {k: scheduling.get(k) for k in ("command_link", "service_loop", "frame_reader")} == {
        "command_link": "SCHED_RR 10",
        "service_loop": "SCHED_RR 10",
        "frame_reader": "SCHED_RR 10",
    }, UNIT_GRANT
    # The dispatcher runs the consumers (work that grows with the frame rate): the unit's nice.
    assert scheduling["frame_dispatcher"] == f"SCHED_OTHER nice {unit_service()['Nice']}"
    assert "why" not in scheduling
    # The kernel agrees: the link's reader and the service loop are the only real-time threads
    # once the stream has ended (its reader is gone), and nothing else inherited it.
    threads = thread_scheduling(unit_daemon.pid).values()
    nice = int(unit_service()["Nice"])
    assert sorted(t for t in threads if t[0] != "SCHED_OTHER") == [("SCHED_RR", 10, nice)] * 2
    log = unit_daemon.log_path.read_text()
    assert "real-time scheduling: the hardware's threads get SCHED_RR 10" in log
    assert "thread frame_reader (camd-frame-read) runs at SCHED_RR 10" in log
    shown = camctl(unit_daemon.url, "status")
    assert shown.returncode == 0, shown.stderr
    assert "daemon.scheduling" in shown.stdout and '"frame_reader": "SCHED_RR 10"' in shown.stdout


@pytest.mark.exclusive
@pytest.mark.slow
def test_under_a_cpu_hog_the_closed_loop_holds_and_no_frame_is_lost(
    unit_daemon: DaemonProcess, tmp_path: Path
) -> None:
    with CamdClient(unit_daemon.url, timeout_s=60) as client, cpu_hog(4) as hog:
        client.set_stage_faults(**DISTURBANCE)
        try:
            for run in range(2):
                # All of the rail ahead (1.2 m, 22 s at the scan's speed): a simulated camera
                # starved by the hog streams late, and a stage at its limit is no loop's fault.
                client.enable_stage()
                client.move_stage(0.0)
                client.start_scan(
                    96, 400, out=str(tmp_path / f"{run}.h5"), line_period_s=T_LINE_S,
                    closed_loop=True,
                )  # fmt: skip
                doc = client.wait_scan(timeout_s=300)
                seen = (run, hog, doc["state"], doc["mismatch_level"], doc["lost_frames"])
                assert doc["state"] == "done", (seen, doc["error"])
                assert doc["mismatch_level"] == "ok", seen
                assert doc["lost_frames"] == 0, seen
                assert doc["motion"]["closed_loop"] == "step_rate"
                assert doc["motion"]["loop_error"] is None
        finally:
            client.set_stage_faults()
        assert client.status()["daemon"]["scheduling"]["closed_loop"] == "SCHED_RR 10"


# -- the daemon without real time ------------------------------------------------------------------


@pytest.mark.skipif(sys.platform != "linux", reason="Linux scheduling")
def test_without_real_time_the_daemon_says_why_or_refuses_when_required(tmp_path: Path) -> None:
    with start(tmp_path / "auto", without_realtime()) as daemon:
        with CamdClient(daemon.url, timeout_s=60) as client:
            client.wait_ready(60)
            scheduling = client.status()["daemon"]["scheduling"]
        assert scheduling["command_link"] == "SCHED_OTHER nice 0"
        assert scheduling["service_loop"] == "SCHED_OTHER nice 0"
        assert scheduling["why"].startswith(NOT_ALLOWED)
        assert all(t[0] == "SCHED_OTHER" for t in thread_scheduling(daemon.pid).values())
    assert f"WARNING camd.daemon.realtime: real-time scheduling: the hardware's threads get " \
        f"SCHED_OTHER nice 0: {NOT_ALLOWED}" in daemon.log_path.read_text()  # fmt: skip

    required = tmp_path / "required"
    with pytest.raises(DaemonStartError) as refused:
        start(required, without_realtime(), '[daemon]\nrealtime = "required"\n').start()
    message = str(refused.value)
    assert "exited with status 2 before it was ready" in message
    assert (
        f'camd serve: daemon.realtime = "required", but {NOT_ALLOWED}; nor nice -5: RLIMIT_NICE '
        "allows no nice below 20 (Nice= or LimitNICE= in the unit); grant it (LimitRTPRIO= in "
        'the systemd unit, or run with CAP_SYS_NICE) or set daemon.realtime = "auto"'
    ) in message
    # Refused before anything started: no archive, no simulated camera.
    assert not (required / "telemetry.sqlite").exists() and not (required / "sim").exists()
