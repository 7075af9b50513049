"""``camd bench fuzz``: the daemon's API fuzzed with schemathesis, from its own /openapi.json.

One daemon on the simulated camera (``camd serve --sim``, loopback). Every operation of its
OpenAPI document gets requests generated from the schema by schemathesis (hypothesis under it),
alternately valid ones (positive) and invalid ones (negative), round after round until
``--requests`` have been sent. Each answer is checked: no 5xx (``not_a_server_error``), a
documented status code, the documented content type and body schema; a request that gets no
answer within ``--timeout`` is a hang. Every Nth refused (4xx) request to an operation that
changes something is sent again on a quiet device (stage stopped) between two snapshots of the
device's state (``camd.bench.device_snapshot``): a refusal must change nothing. At the end the
daemon must still answer GET /api/v1/status, its process alive.

Operations that would make the run destructive or long are left out or neutralised
(``EXCLUDED``, ``neutralise``, ``undo``): the report names them.

The same driver (``fuzz``) runs the short fuzzing of the test suite (tests/test_fuzz_api.py).
schemathesis is a test extra: imported only here, and the bench says what to install without it.
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
import tempfile
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from camd.daemon.control import ANONYMOUS

if TYPE_CHECKING:
    from schemathesis import APIOperation, Case

INSTALL = "install the test extra: pip install -e '.[test]' (schemathesis)"
DEFAULT_REQUESTS = 5000
DEFAULT_TIMEOUT_S = 30.0
DEFAULT_SNAPSHOT_EVERY = 10
API = "/api/v1"

# Left out, with the reason (method, path) -> why.
EXCLUDED: dict[tuple[str, str], str] = {
    ("POST", f"{API}/reset"): "resets the camera: seconds each, and undoes what the others set",
    ("POST", f"{API}/sim/fail-next"): "makes the next device command fail on purpose (a 5xx "
    "by design); its refusals are tested in tests/test_inject.py",
    ("POST", f"{API}/link/command"): "sends any frame to the camera by design (RESET, "
    "SIM_FAIL_NEXT, START_STREAM behind the daemon's back); the conformance suite and "
    "tests/test_conformance.py test it",
    ("POST", f"{API}/wheel/acquire"): "waits for the wheel to turn to every channel, pass "
    "after pass: seconds to minutes per request (tests/test_wheel_stack.py covers it)",
}
MAX_FRAMES = 4  # stream/acquire and stream/start: frames taken at most
MAX_LINES = 20  # scan/start: lines at most
MAX_ACQUIRE_TIMEOUT_S = 10.0
READ_METHODS = ("GET", "HEAD", "OPTIONS")


class FuzzUnavailable(RuntimeError):
    """schemathesis is not installed."""


def _is_timeout(exc: BaseException) -> bool:
    """``requests``' timeouts (ReadTimeout, ConnectTimeout) without importing requests."""
    return any(k.__name__ in ("Timeout", "TimeoutError") for k in type(exc).__mro__)


def neutralise(case: Case[Any], scratch: Path, number: int) -> None:
    """Bound what an accepted request would do, in place: files go to ``scratch``, at most a
    few frames or lines, moves and homing return at once (``wait`` false). Invalid values
    (the wrong type) are left alone: they must still be refused."""
    body = case.body
    if not isinstance(body, dict):
        return
    path = case.operation.path
    for key in ("record", "out"):
        if isinstance(body.get(key), str):
            body[key] = str(scratch / f"fuzz-{number}.h5")
    if path in (f"{API}/stream/acquire", f"{API}/stream/start"):
        frames = body.get("frames")
        if isinstance(frames, int) and not isinstance(frames, bool) and frames > MAX_FRAMES:
            body["frames"] = 1 + frames % MAX_FRAMES
        timeout = body.get("timeout_s")
        if isinstance(timeout, int | float) and timeout > MAX_ACQUIRE_TIMEOUT_S:
            body["timeout_s"] = MAX_ACQUIRE_TIMEOUT_S
    if path == f"{API}/scan/start":
        lines = body.get("lines")
        if isinstance(lines, int) and not isinstance(lines, bool) and lines > MAX_LINES:
            body["lines"] = 1 + lines % MAX_LINES
    if path in (f"{API}/motion/move", f"{API}/motion/home") and body.get("wait") is True:
        body["wait"] = False


def undo(case: Case[Any]) -> list[tuple[str, str, dict[str, Any] | None]]:
    """What puts the daemon back in a state where the other operations can run, after
    ``case`` was accepted: (method, path, JSON body) requests, sent as the same client."""
    path = case.operation.path
    method = case.operation.method.upper()
    if (method, path) == ("POST", f"{API}/estop"):
        # The emergency stop latches: released first, then the stage enabled again.
        return [
            ("POST", f"{API}/estop/release", None),
            ("POST", f"{API}/motion/enable", {"on": True}),
        ]
    if (method, path) == ("POST", f"{API}/motion/estop"):
        return [("POST", f"{API}/motion/enable", {"on": True})]
    if (method, path) == ("POST", f"{API}/control"):
        return [("DELETE", f"{API}/control", None)]
    if (method, path) == ("POST", f"{API}/stream/start"):
        return [("POST", f"{API}/stream/stop", None)]
    if (method, path) == ("POST", f"{API}/scan/start"):
        return [("POST", f"{API}/scan/stop", None)]
    return []


def _client_header(case: Case[Any]) -> dict[str, str]:
    """The case's client, named: an undo without a body needs the header (a bodyless POST
    without it is refused, docs/api.md), and "anonymous" is who a request without one is."""
    headers: Mapping[str, Any] = case.headers or {}
    name = next((v for k, v in headers.items() if k.lower() == "x-camd-client"), ANONYMOUS)
    return {"X-Camd-Client": str(name)}


def fuzz(
    url: str,
    *,
    requests: int,
    seed: int = 0,
    scratch: Path,
    timeout_s: float = DEFAULT_TIMEOUT_S,
    snapshot_every: int = DEFAULT_SNAPSHOT_EVERY,
    alive: Callable[[], bool] = lambda: True,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Fuzz the daemon at ``url`` with about ``requests`` generated requests (module
    docstring); the counts, failures and checks as one JSON-able document."""
    try:
        import hypothesis
        import schemathesis
        from schemathesis import checks
        from schemathesis.core.result import Err
    except ImportError as exc:
        raise FuzzUnavailable(f"camd bench fuzz needs schemathesis ({exc}); {INSTALL}") from None
    import httpx

    from camd.bench.device_snapshot import snapshot
    from camd.client import CamdClient
    from camd.motion.stage import STOPPED_STATES

    schema = schemathesis.openapi.from_url(f"{url}/openapi.json")
    operations: list[APIOperation[Any, Any, Any, Any]] = []
    excluded: dict[str, str] = {}
    for result in schema.get_all_operations():
        if isinstance(result, Err):
            raise FuzzUnavailable(f"the daemon's /openapi.json is invalid: {result.err()}")
        op = result.ok()
        key = (op.method.upper(), op.path)
        if key in EXCLUDED:
            excluded[f"{key[0]} {key[1]}"] = EXCLUDED[key]
        else:
            operations.append(op)
    response_checks = [
        checks.not_a_server_error,
        checks.status_code_conformance,
        checks.content_type_conformance,
        checks.response_schema_conformance,
    ]
    sent: collections.Counter[str] = collections.Counter()
    codes: collections.Counter[int] = collections.Counter()
    server_errors: list[str] = []
    hangs: list[str] = []
    transport_errors: list[str] = []
    failures: dict[str, str] = {}  # one example per check failure (first line)
    undo_failures: list[str] = []
    snap: collections.Counter[str] = collections.Counter()  # checked, unchanged, not_reproduced
    changed: list[str] = []
    rejected_changing = 0
    helper = httpx.Client(base_url=url, timeout=timeout_s)
    client = CamdClient(url, timeout_s=timeout_s)
    total = 0
    t0 = time.monotonic()

    def describe(case: Case[Any], what: str) -> str:
        body = json.dumps(case.body, default=repr)[:300] if case.body is not None else ""
        query = f" query={case.query}" if case.query else ""
        return f"{case.operation.label}{query} {body}: {what}"

    def quiet() -> None:
        """Stop the stage and wait for it to stand (a refused request is replayed then)."""
        helper.post(f"{API}/motion/stop")
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            reading = helper.get(f"{API}/motion").json().get("reading", {})
            if reading.get("state") in STOPPED_STATES:
                return
            time.sleep(0.05)

    def check_refusal(case: Case[Any]) -> None:
        quiet()
        before = snapshot(client)
        again = case.call(base_url=url, timeout=timeout_s)
        if not 400 <= again.status_code < 500:
            snap["not_reproduced"] += 1
            for method, path, body in undo(case):
                helper.request(method, path, json=body, headers=_client_header(case))
            return
        after = snapshot(client)
        snap["checked"] += 1
        if after == before:
            snap["unchanged"] += 1
        else:
            which = sorted(k for k in before if before[k] != after[k])
            changed.append(describe(case, f"changed {which}"))

    def one(case: Case[Any]) -> None:
        nonlocal total, rejected_changing
        if total >= requests:
            return
        total += 1
        label = case.operation.label
        sent[label] += 1
        neutralise(case, scratch, total)
        try:
            response = case.call(base_url=url, timeout=timeout_s)
        except Exception as exc:
            if _is_timeout(exc):
                hangs.append(describe(case, f"no answer within {timeout_s:g} s"))
            else:
                transport_errors.append(describe(case, f"{type(exc).__name__}: {exc}"))
            return
        status = response.status_code
        codes[status] += 1
        if status >= 500:
            server_errors.append(describe(case, f"{status} {response.text[:300]}"))
        found: list[BaseException] = []
        try:
            case.validate_response(response, checks=response_checks)
        except BaseExceptionGroup as group:  # schemathesis' FailureGroup
            found.extend(group.exceptions)
        except Exception as exc:
            found.append(exc)
        for failure in found:
            title = str(getattr(failure, "title", "") or type(failure).__name__)
            message = str(getattr(failure, "message", "") or failure)
            what = f"{status}: {message.strip()[:300]}; answer {response.text[:300]}"
            failures.setdefault(f"{label}: {title}", describe(case, what))
        if 200 <= status < 300:
            for method, path, body in undo(case):
                answer = helper.request(method, path, json=body, headers=_client_header(case))
                if answer.status_code >= 300:
                    undo_failures.append(f"{method} {path} after {label}: {answer.text[:200]}")
        elif 400 <= status < 500 and case.operation.method.upper() not in READ_METHODS:
            rejected_changing += 1
            if snapshot_every > 0 and rejected_changing % snapshot_every == 0:
                check_refusal(case)

    settings = hypothesis.settings(
        deadline=None,
        database=None,
        phases=[hypothesis.Phase.generate],
        suppress_health_check=list(hypothesis.HealthCheck),
    )
    modes = [schemathesis.GenerationMode.POSITIVE, schemathesis.GenerationMode.NEGATIVE]
    try:
        rounds = 0
        cannot: set[tuple[int, int]] = set()
        while total < requests:
            rounds += 1
            before_round = total
            left = max(1, len(operations) * len(modes))
            per = max(1, -(-(requests - total) // left))  # ceil
            for index, op in enumerate(operations):
                for m, mode in enumerate(modes):
                    if total >= requests or (index, m) in cannot:
                        continue
                    strategy = op.as_strategy(generation_mode=mode)
                    test = hypothesis.given(case=strategy)(one)
                    test = hypothesis.settings(settings, max_examples=per)(test)
                    try:
                        hypothesis.seed(hash((seed, rounds, index, m)) & 0xFFFF_FFFF)(test)()
                    except hypothesis.errors.Unsatisfiable:
                        cannot.add((index, m))  # no invalid request exists (no parameters)
                if total >= requests:
                    break
            if progress is not None:
                progress(f"round {rounds}: {total} requests, {time.monotonic() - t0:.0f} s")
            if total == before_round:
                break  # nothing more to generate
        status = helper.get(f"{API}/status", timeout=timeout_s)
        answers = status.status_code == 200
    except httpx.HTTPError as exc:
        transport_errors.append(f"after the run: {type(exc).__name__}: {exc}")
        answers = False
    finally:
        helper.close()
        client.close()
    return {
        "requests": total,
        "seconds": round(time.monotonic() - t0, 1),
        "seed": seed,
        "operations": len(operations),
        "excluded": excluded,
        "per_operation": dict(sorted(sent.items())),
        "status_codes": {str(k): v for k, v in sorted(codes.items())},
        "server_errors": server_errors,
        "hangs": hangs,
        "timeout_s": timeout_s,
        "transport_errors": transport_errors,
        "check_failures": failures,
        "undo_failures": undo_failures,
        "refusals_snapshot": {
            "checked": snap["checked"],
            "unchanged": snap["unchanged"],
            "changed": changed,
            "not_reproduced": snap["not_reproduced"],
        },
        "snapshot_every": snapshot_every,
        "status_answers": answers,
        "alive": answers and alive(),
    }


# -- camd bench fuzz -----------------------------------------------------------------------------


def add_options(p: argparse.ArgumentParser) -> None:
    """The options of ``camd bench fuzz`` but ``--json`` (camd.bench.command adds it)."""
    p.add_argument(
        "--requests",
        type=int,
        default=DEFAULT_REQUESTS,
        help=f"requests to send (default {DEFAULT_REQUESTS})",
    )
    p.add_argument("--seed", type=int, default=0, help="generation seed (default 0)")
    p.add_argument(
        "--timeout",
        type=float,
        default=DEFAULT_TIMEOUT_S,
        help=f"a request not answered within this many seconds is a hang ({DEFAULT_TIMEOUT_S:g})",
    )
    p.add_argument(
        "--snapshot-every",
        type=int,
        default=DEFAULT_SNAPSHOT_EVERY,
        help="check the device's state around every Nth refused state-changing request "
        f"(default {DEFAULT_SNAPSHOT_EVERY}; 0: never)",
    )


def run(args: argparse.Namespace) -> int:
    if args.requests < 1 or not args.timeout > 0 or args.snapshot_every < 0:
        print(
            "camd bench fuzz: --requests must be >= 1, --timeout > 0, --snapshot-every >= 0",
            file=sys.stderr,
        )
        return 2
    from camd.cli._daemon_proc import DaemonProcess

    def progress(line: str) -> None:
        print(f"camd bench fuzz: {line}", file=sys.stderr, flush=True)

    with tempfile.TemporaryDirectory(prefix="camd-bench-fuzz-") as tmp:
        root = Path(tmp)
        config = root / "camd.toml"
        config.write_text('[sensor]\nname = "hr400"\nbridge = "fpga"\n')
        scratch = root / "files"
        scratch.mkdir()
        try:
            with DaemonProcess(
                root / "daemon",
                record_dirs=[scratch],  # where neutralise() sends every file
                extra_args=["--config", str(config)],
                env={"CAMD_TOKEN": ""},
            ) as daemon:
                from camd.client import CamdClient

                with CamdClient(daemon.url) as client:
                    client.wait_ready(60)
                    client.write_registers({"WIN_ROWS": 16, "EXPOSURE": 4})  # short frames
                result = fuzz(
                    daemon.url,
                    requests=args.requests,
                    seed=args.seed,
                    scratch=scratch,
                    timeout_s=args.timeout,
                    snapshot_every=args.snapshot_every,
                    alive=lambda: daemon.running,
                    progress=progress,
                )
            result["daemon_exit_code"] = daemon.exit_code
        except FuzzUnavailable as exc:
            print(f"camd bench fuzz: {exc}", file=sys.stderr)
            return 1
    if args.json:
        print(json.dumps(result))
    else:
        _print(result)
    bad = (
        result["server_errors"]
        or result["hangs"]
        or result["transport_errors"]
        or result["check_failures"]
        or result["refusals_snapshot"]["changed"]
        or not result["alive"]
    )
    return 1 if bad else 0


def _print(r: dict[str, Any]) -> None:
    print(
        f"API fuzzing: {r['requests']} requests to {r['operations']} operations in "
        f"{r['seconds']:g} s (seed {r['seed']})"
    )
    print("requests per operation:")
    for label, count in r["per_operation"].items():
        print(f"  {count:6d}  {label}")
    print("left out:")
    for label, why in r["excluded"].items():
        print(f"  {label}: {why}")
    print("status codes: " + ", ".join(f"{k}: {v}" for k, v in r["status_codes"].items()))
    print(f"server errors (5xx): {len(r['server_errors'])}")
    for line in r["server_errors"][:20]:
        print(f"  {line}")
    print(f"hangs (no answer within {r['timeout_s']:g} s): {len(r['hangs'])}")
    for line in r["hangs"][:20]:
        print(f"  {line}")
    if r["transport_errors"]:
        print(f"transport errors: {len(r['transport_errors'])}")
        for line in r["transport_errors"][:20]:
            print(f"  {line}")
    print(f"schema conformance failures: {len(r['check_failures'])}")
    for key in r["check_failures"]:
        print(f"  {key}")
    snap = r["refusals_snapshot"]
    print(
        f"refused requests replayed between device snapshots (every {r['snapshot_every']}th "
        f"refused state-changing request): {snap['checked']} checked, {snap['unchanged']} "
        f"unchanged, {len(snap['changed'])} changed, {snap['not_reproduced']} accepted on "
        "the quiet device"
    )
    for line in snap["changed"][:20]:
        print(f"  {line}")
    print(f"daemon alive and answering /api/v1/status: {'yes' if r['alive'] else 'NO'}")
