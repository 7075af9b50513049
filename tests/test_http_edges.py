"""The HTTP edge of the daemon against browsers and untrusted clients (docs/api.md, "Browsers
and untrusted clients").

A real ``camd serve --sim`` on loopback without a token (the default, where any web page the
user opens could reach it), driven with raw sockets, httpx and a WebSocket client:

- a page of another origin cannot change anything, not even by the "simple" requests (a POST
  without a body) that a browser sends without asking first; nor open the live WebSocket; nor
  reach the daemon through a DNS name pointed at 127.0.0.1;
- a bodyless change needs the X-Camd-Client header (or a JSON body), except the emergency stop,
  which a shell's ``curl -X POST`` still makes;
- a 50 MB body is refused before it is read, its memory never taken; a chunked one is refused
  once it passes the limit;
- 100 half-sent requests are closed after ``api.request_timeout_s`` while others are served;
- a long bad value is cut in the error that names it;
- the token never reaches the daemon's log, even at debug level.
"""

from __future__ import annotations

import io
import json
import logging
import re
import socket
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import httpx
import pytest
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from camd.cli._daemon_proc import DaemonProcess
from camd.client import CamdClient
from camd.daemon.config import ConfigError, config_from_dict
from camd.daemon.serve import RedactSecrets

API = "/api/v1"
WAIT_S = 120.0  # generous: the suite shares 2 cores
EVIL = "http://evil.example"
ALLOWED = "http://viewer.example:9000"  # the test config's api.allowed_origins
REQUEST_TIMEOUT_S = 2.0  # the test config's api.request_timeout_s
MAX_BODY_BYTES = 65536  # the default api.max_body_bytes
CLIENT = {"X-Camd-Client": "edge-tester"}
SECRET = "SECRET-7f3a9c-token"


@dataclass
class Daemon:
    """A daemon under test: its URL, pid and log."""

    url: str
    pid: int
    process: DaemonProcess
    host: str = field(init=False)
    port: int = field(init=False)

    def __post_init__(self) -> None:
        parts = urlsplit(self.url)
        assert parts.hostname is not None and parts.port is not None
        self.host, self.port = parts.hostname, parts.port

    def rss_kib(self) -> int:
        """The daemon's resident memory (VmRSS), KiB."""
        for line in Path(f"/proc/{self.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
        raise AssertionError(f"no VmRSS in /proc/{self.pid}/status")

    def raw(self, timeout_s: float = 30.0) -> socket.socket:
        """A new TCP connection to the daemon."""
        return socket.create_connection((self.host, self.port), timeout=timeout_s)


def _start(data: Path, config: str, env: dict[str, str]) -> DaemonProcess:
    (data.parent / "camd.toml").write_text(config)
    daemon = DaemonProcess(
        data, env=env, extra_args=["--config", str(data.parent / "camd.toml")],
        start_timeout_s=WAIT_S,
    )  # fmt: skip
    daemon.start()
    with CamdClient(daemon.url, timeout_s=60, token=env.get("CAMD_TOKEN") or "") as client:
        client.wait_ready(WAIT_S)
    return daemon


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Daemon]:
    """A daemon without a token, a short request timeout and one allowed foreign origin."""
    config = f'[api]\nrequest_timeout_s = {REQUEST_TIMEOUT_S}\nallowed_origins = ["{ALLOWED}"]\n'
    process = _start(tmp_path_factory.mktemp("edges") / "data", config, {"CAMD_TOKEN": ""})
    try:
        yield Daemon(process.url, process.pid, process)
    finally:
        process.stop()


# -- helpers --------------------------------------------------------------------------------


def _error(answer: httpx.Response, status: int, code: str) -> str:
    assert answer.status_code == status, answer.text
    body = answer.json()
    assert body["code"] == code, body
    return str(body["error"])


def _traces(d: Daemon) -> dict[str, Any]:
    """What a refused request must not change: the events, the state, the stage, the last
    training and the stream and scan documents."""
    with httpx.Client(base_url=d.url, timeout=60) as http:
        status = http.get(f"{API}/status").json()
        return {
            "events": http.get(f"{API}/events", params={"limit": 100000}).json()["events"],
            "state": status["state"],
            "acquisition": status["acquisition"],
            "stage": http.get(f"{API}/motion").json()["reading"]["state"],
            "train": http.get(f"{API}/train").json()["t_s"],
            "stream": http.get(f"{API}/stream").json()["frames_requested"],
            "scan": http.get(f"{API}/scan").json()["state"],
        }


def _read_response(sock: socket.socket) -> tuple[int, dict[str, str], bytes]:
    """One HTTP response from ``sock``: status, headers (lower-case names), body."""
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = sock.recv(65536)
        if not chunk:
            raise AssertionError(f"connection closed before a response; got {data!r}")
        data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    status = int(lines[0].split()[1])
    headers = {k.strip().lower(): v.strip() for k, _, v in (x.partition(":") for x in lines[1:])}
    length = int(headers.get("content-length", "0"))
    while len(body) < length:
        chunk = sock.recv(65536)
        if not chunk:
            break
        body += chunk
    return status, headers, body


def _headers(d: Daemon, method: str, path: str, extra: str = "") -> bytes:
    return (
        f"{method} {path} HTTP/1.1\r\nHost: {d.host}:{d.port}\r\n"
        f"Content-Type: application/json\r\nX-Camd-Client: edge-tester\r\n{extra}\r\n"
    ).encode()


# -- cross-site requests --------------------------------------------------------------------

FOREIGN_PAGE = (
    "refused: this request comes from a page at {origin}, not one of this daemon's own pages; "
    "a page of another site may not use the camera, not even to stop it (`camctl estop`, the "
    "live view at /live and `curl -X POST .../api/v1/estop` always can). If the page is yours, "
    "add its origin to api.allowed_origins (docs/config.md)"
)


@pytest.mark.parametrize(
    "path",
    [f"{API}/estop", f"{API}/motion/estop", f"{API}/motion/stop", f"{API}/reset",
     f"{API}/train", f"{API}/stream/stop", f"{API}/scan/stop"],
)  # fmt: skip
def test_a_page_of_another_site_changes_nothing_with_a_bodyless_post(
    daemon: Daemon, path: str
) -> None:
    """What a browser sends for ``fetch(url, {method: "POST", mode: "no-cors"})`` or a form
    on evil.example: no body, no custom header, its Origin."""
    before = _traces(daemon)
    with httpx.Client(base_url=daemon.url, timeout=60) as http:
        for origin in (EVIL, "null", f"http://{daemon.host}:{daemon.port + 1}"):
            message = _error(http.post(path, headers={"Origin": origin}), 403, "foreign_origin")
            assert message == FOREIGN_PAGE.format(origin=origin)
        # Nor with what a browser would send only after a preflight the daemon never grants.
        answer = http.post(path, json={}, headers={"Origin": EVIL, **CLIENT})
        _error(answer, 403, "foreign_origin")
    assert _traces(daemon) == before


def test_the_daemons_own_pages_and_allowed_origins_are_served(daemon: Daemon) -> None:
    with httpx.Client(base_url=daemon.url, timeout=60) as http:
        for origin in (daemon.url, ALLOWED, ALLOWED.upper()):
            answer = http.post(f"{API}/ping", json={"count": 1}, headers={"Origin": origin})
            assert answer.status_code == 200, (origin, answer.text)
            assert answer.json()["ok"] == 1
        # The daemon's own page reached by another of its addresses (localhost, not 127.0.0.1).
        own = f"http://localhost:{daemon.port}"
        answer = http.post(
            f"{API}/ping", headers={"Origin": own, "Host": f"localhost:{daemon.port}"}
        )
        assert answer.status_code == 200, answer.text
        # Reading is refused to a foreign page too (its fetch would carry the Origin).
        _error(http.get(f"{API}/status", headers={"Origin": EVIL}), 403, "foreign_origin")


NEEDS_CLIENT = (
    "POST {path} changes the camera, and this request has neither a JSON body (Content-Type: "
    "application/json) nor the X-Camd-Client header: send one of them (camctl, CamdClient and "
    "the live view always send X-Camd-Client). A web page of another site cannot send either "
    "without the daemon's leave, which it never gives"
)


def test_a_bodyless_change_without_the_client_header_is_refused(daemon: Daemon) -> None:
    """No Origin: not a browser's cross-site request as far as the daemon can tell, but a
    browser that omits Origin (older ones did on form posts) must still not get through."""
    before = _traces(daemon)
    with httpx.Client(base_url=daemon.url, timeout=60) as http:
        for path in (f"{API}/reset", f"{API}/train", f"{API}/stream/stop", f"{API}/ping"):
            message = _error(http.post(path), 403, "client_header_required")
            assert message == NEEDS_CLIENT.format(path=path)
        # A form's or a text/plain fetch's body is no JSON body.
        for kind in ("text/plain", "application/x-www-form-urlencoded", "multipart/form-data"):
            answer = http.post(
                f"{API}/ping", content=b'{"count": 1}', headers={"Content-Type": kind}
            )
            _error(answer, 403, "client_header_required")
        answer = http.delete(f"{API}/control")
        assert "DELETE /api/v1/control changes the camera" in _error(
            answer, 403, "client_header_required"
        )
    assert _traces(daemon) == before
    with httpx.Client(base_url=daemon.url, timeout=60) as http:
        assert http.post(f"{API}/ping", headers=CLIENT).json()["count"] == 10
        assert http.post(f"{API}/ping", json={"count": 2}).json()["ok"] == 2
        assert http.delete(f"{API}/control", headers=CLIENT).json()["holder"] is None


def test_the_live_websocket_refuses_a_page_of_another_site(daemon: Daemon) -> None:
    ws = f"ws://{daemon.host}:{daemon.port}{API}/live/ws"
    for origin in (EVIL, "null"):
        with pytest.raises(InvalidStatus) as refused:
            connect(ws, origin=origin, open_timeout=30).close()
        assert refused.value.response.status_code == 403
        body = json.loads(refused.value.response.body or b"{}")
        assert body == {"code": "foreign_origin", "error": FOREIGN_PAGE.format(origin=origin)}
    for origin in (daemon.url, ALLOWED, None):  # its own page, an allowed one, not a browser
        with connect(ws, origin=origin, open_timeout=30) as socket_:
            socket_.ping().wait(30)
            if origin is None:  # an open WebSocket is no request being sent: never timed out
                time.sleep(REQUEST_TIMEOUT_S * 2)
                socket_.ping().wait(30)


def test_a_dns_name_pointed_at_loopback_does_not_reach_a_daemon_without_token(
    daemon: Daemon,
) -> None:
    """DNS rebinding: evil.example resolved to 127.0.0.1 makes the daemon same-origin for the
    page; its requests then carry ``Host: evil.example:PORT``."""
    before = _traces(daemon)
    host = f"evil.example:{daemon.port}"
    with httpx.Client(base_url=daemon.url, timeout=60) as http:
        message = _error(http.get(f"{API}/status", headers={"Host": host}), 403, "foreign_host")
        assert message == (
            f"refused: this request is addressed to {host}, a name that this daemon without "
            "a token does not answer to (a web page could point such a name at 127.0.0.1 to "
            "reach it); address it by IP (127.0.0.1) or as localhost, add the origin "
            "http://NAME:PORT to api.allowed_origins, or set api.token"
        )
        headers = {"Host": host, "Origin": f"http://{host}", **CLIENT}
        _error(http.post(f"{API}/estop", headers=headers), 403, "foreign_host")
        for allowed in (f"localhost:{daemon.port}", f"[::1]:{daemon.port}", "viewer.example:9000"):
            assert http.get(f"{API}/status", headers={"Host": allowed}).status_code == 200
    assert _traces(daemon) == before


# -- request size ---------------------------------------------------------------------------


def _send_quietly(sock: socket.socket, chunks: Iterator[bytes], sent: list[int]) -> None:
    """Send until done or until the daemon closes (it may, once it has refused)."""
    try:
        for chunk in chunks:
            sock.sendall(chunk)
            sent[0] += len(chunk)
    except OSError:
        pass


def test_a_50_mb_body_is_refused_before_it_is_read(daemon: Daemon) -> None:
    size = 50_000_000
    with httpx.Client(base_url=daemon.url, timeout=60) as http:  # warm the code paths
        http.post(f"{API}/ping", content=b"x" * (MAX_BODY_BYTES + 1), headers=CLIENT)
    rss_before = daemon.rss_kib()
    timings, statuses = [], []
    senders: list[threading.Thread] = []
    sent = [[0] for _ in range(4)]
    socks = [daemon.raw() for _ in range(4)]
    try:
        for i, sock in enumerate(socks):  # four at once, as the probe did
            t0 = time.monotonic()
            sock.sendall(_headers(daemon, "POST", f"{API}/ping", f"Content-Length: {size}\r\n"))
            status, _, body = _read_response(sock)  # before a byte of the body is sent
            timings.append(time.monotonic() - t0)
            statuses.append(status)
            assert json.loads(body) == {
                "code": "too_large",
                "error": f"the request body is {size} bytes, more than the {MAX_BODY_BYTES} this "
                "daemon takes (api.max_body_bytes); no request of this API needs that much: "
                "check what is being sent",
            }
            chunks = (b" " * 1_000_000 for _ in range(size // 1_000_000))
            sender = threading.Thread(target=_send_quietly, args=(sock, chunks, sent[i]))
            sender.start()
            senders.append(sender)
        with httpx.Client(base_url=daemon.url, timeout=60) as http:  # others are served meanwhile
            t0 = time.monotonic()
            assert http.get(f"{API}/status").status_code == 200
            status_s = time.monotonic() - t0
        rss_during = daemon.rss_kib()
        for sender in senders:
            sender.join(WAIT_S)
    finally:
        for sock in socks:
            sock.close()
    rss_after = daemon.rss_kib()
    print(
        f"50 MB bodies: 413 after {max(timings):.3f} s (slowest of 4); body bytes each client "
        f"sent after it: {[s[0] for s in sent]}; GET status meanwhile "
        f"{status_s:.3f} s; RSS {rss_before / 1024:.1f} -> {rss_during / 1024:.1f} -> "
        f"{rss_after / 1024:.1f} MiB"
    )
    assert statuses == [413] * 4
    assert max(rss_during, rss_after) - rss_before < 8 * 1024  # flat: not a body's worth


def test_a_chunked_body_is_refused_once_it_passes_the_limit(daemon: Daemon) -> None:
    rss_before = daemon.rss_kib()
    chunk = b" " * 16384
    framed = f"{len(chunk):x}\r\n".encode() + chunk + b"\r\n"
    with daemon.raw() as sock:
        sock.sendall(_headers(daemon, "POST", f"{API}/ping", "Transfer-Encoding: chunked\r\n"))
        sent = [0]
        sender = threading.Thread(
            target=_send_quietly, args=(sock, (framed for _ in range(3000)), sent)
        )  # 49 MB, unless the daemon closes first
        sender.start()
        status, _, body = _read_response(sock)
        sender.join(WAIT_S)
    assert status == 413
    assert json.loads(body) == {
        "code": "too_large",
        "error": f"the request body is more than the {MAX_BODY_BYTES} bytes this daemon takes "
        "(api.max_body_bytes): it was sent chunked and refused once it passed them; no request "
        "of this API needs that much: check what is being sent",
    }
    assert daemon.rss_kib() - rss_before < 8 * 1024


def test_a_body_at_the_limit_is_read_and_one_byte_more_is_not(daemon: Daemon) -> None:
    body = b'{"count": 1}'
    at_limit = body + b" " * (MAX_BODY_BYTES - len(body))
    with httpx.Client(base_url=daemon.url, timeout=60, headers=CLIENT) as http:
        answer = http.post(
            f"{API}/ping", content=at_limit, headers={"Content-Type": "application/json"}
        )
        assert answer.status_code == 200 and answer.json()["ok"] == 1
        answer = http.post(
            f"{API}/ping", content=at_limit + b" ", headers={"Content-Type": "application/json"}
        )
        _error(answer, 413, "too_large")
        # The connection goes on serving after a refusal (the rest of the body is read and dropped).
        assert http.get(f"{API}/status").status_code == 200


def test_a_body_of_too_many_json_values_is_refused_before_fastapi_parses_it(
    daemon: Daemon,
) -> None:
    """FastAPI parses and validates on the event loop: 64 KiB of invalid entries held it for
    140 ms a request. More than 1000 values (no request has a hundred) are refused first:
    counted on the event loop in a small body, on a worker thread in a larger one."""
    small = {"values": {"GAIN": [1] * 1500}}  # 3 kB: 1 + 1 + 1 + 1500 values
    large = {"values": {f"R{i}": [1] for i in range(999)}}  # 12 kB: 1 + 1 + 999 x 2
    with httpx.Client(base_url=daemon.url, timeout=60, headers=CLIENT) as http:
        for body, count in ((small, 1503), (large, 2000)):
            message = _error(http.post(f"{API}/registers", json=body), 413, "too_large")
            assert message == (
                f"the request body is {count} JSON values (objects, lists, numbers, strings...), "
                "more than the 1000 this daemon takes; no request of this API needs that much: "
                "check what is being sent"
            )
        # 1000 exactly: read, validated, refused for what it says (ten problems shown).
        values = {f"R{i}": [1] for i in range(499)}
        message = _error(http.post(f"{API}/registers", json={"values": values}), 400, "bad_request")
        assert message.endswith("; and 489 more problems")


# -- half-sent requests ---------------------------------------------------------------------


def test_half_sent_requests_are_closed_after_the_request_timeout(daemon: Daemon) -> None:
    host = f"Host: {daemon.host}:{daemon.port}\r\n"
    partial_headers = f"GET {API}/status HTTP/1.1\r\n{host}X-Camd-Client: slow".encode()
    half_body = (
        f"POST {API}/ping HTTP/1.1\r\n{host}Content-Type: application/json\r\n"
        "Content-Length: 100\r\n\r\n" + '{"count": 1' + " " * 39
    ).encode()
    kinds = ["headers"] * 40 + ["body"] * 40 + ["nothing"] * 20
    socks = [daemon.raw(timeout_s=REQUEST_TIMEOUT_S + 60) for _ in kinds]
    t0 = time.monotonic()
    for sock, kind in zip(socks, kinds, strict=True):
        if kind != "nothing":
            sock.sendall(partial_headers if kind == "headers" else half_body)
    with httpx.Client(base_url=daemon.url, timeout=60) as http:  # served meanwhile
        assert http.get(f"{API}/status").status_code == 200
        served_s = time.monotonic() - t0
    closed_s: list[float] = []
    answers: dict[str, set[bytes]] = {kind: set() for kind in kinds}
    for sock, kind in zip(socks, kinds, strict=True):
        received = b""
        with sock:
            while chunk := sock.recv(65536):  # until the daemon closes (or 60 s: a failure)
                received += chunk
        closed_s.append(time.monotonic() - t0)
        answers[kind].add(received.split(b"\r\n", 1)[0])
        if kind != "nothing":
            body = json.loads(received.partition(b"\r\n\r\n")[2])
            assert body == {
                "code": "request_timeout",
                "error": f"the request was not complete within {REQUEST_TIMEOUT_S:g} s "
                "(api.request_timeout_s): its headers or its body stopped coming; the "
                "connection is closed",
            }
    print(
        f"100 half-sent requests: all closed {max(closed_s):.2f} s after they were sent "
        f"(timeout {REQUEST_TIMEOUT_S:g} s); a GET status meanwhile answered in {served_s:.3f} s"
    )
    assert answers == {
        "headers": {b"HTTP/1.1 408 Request Timeout"},
        "body": {b"HTTP/1.1 408 Request Timeout"},
        "nothing": {b""},
    }
    assert max(closed_s) < REQUEST_TIMEOUT_S + 30  # generous for a busy machine


# -- bad values cut in errors ---------------------------------------------------------------


def test_a_long_bad_value_is_cut_in_the_error(daemon: Daemon) -> None:
    with httpx.Client(base_url=daemon.url, timeout=60, headers=CLIENT) as http:
        value = "x" * 50000
        message = _error(http.post(f"{API}/mode", json={"mode": value}), 400, "bad_request")
        assert message == f"mode: '{'x' * 79}... (50002 characters) is not valid; use area or tdi"
        path = f"{API}/" + "a" * 10000
        message = _error(http.get(path), 404, "not_found")
        assert (
            message
            == f"no such endpoint {path[:80]}... (10008 characters); see /docs or docs/api.md"
        )
        # Hundreds of bad parameters: the first ten, and how many more.
        extra = {f"k{i}": 1 for i in range(500)}
        message = _error(
            http.post(f"{API}/mode", json={"mode": "tdi", **extra}), 400, "bad_request"
        )
        assert message.endswith("; and 490 more problems")
        assert message.count("unknown parameter") == 10
        # A name the daemon's services echo (no such register): cut as well.
        answer = http.post(f"{API}/registers", json={"values": {"N" * 40000: 1}})
        message = _error(answer, 400, "bad_request")
        assert len(message) < 500 and re.search(r"N{99}\.\.\. \(4000\d characters\)", message)


# -- the token and the log ------------------------------------------------------------------


@pytest.fixture(scope="module")
def token_daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Daemon]:
    """A daemon with a token that logs everything (debug: every HTTP request too)."""
    data = tmp_path_factory.mktemp("edges-token") / "data"
    process = _start(data, '[daemon]\nlog_level = "debug"\n', {"CAMD_TOKEN": SECRET})
    try:
        yield Daemon(process.url, process.pid, process)
    finally:
        process.stop()


def test_the_token_never_reaches_the_log(token_daemon: Daemon) -> None:
    d = token_daemon
    ws = f"ws://{d.host}:{d.port}{API}/live/ws"
    with connect(f"{ws}?token={SECRET}", open_timeout=30) as live:
        live.ping().wait(30)
    with pytest.raises(InvalidStatus):
        connect(f"{ws}?token={SECRET}x", open_timeout=30)
    with httpx.Client(base_url=d.url, timeout=60) as http:
        page = http.get(f"/live?token={SECRET}", follow_redirects=True)
        assert page.status_code == 200 and "text/html" in page.headers["content-type"]
        assert http.get(f"{API}/status?token={SECRET}").status_code == 200
        assert (
            http.get(f"{API}/status", headers={"Authorization": f"Bearer {SECRET}"}).status_code
            == 200
        )
        assert http.get(f"{API}/status?token=not-{SECRET}").status_code == 401
    d.process.stop()  # everything it logged is in the file now
    log = d.process.log_path.read_text()
    assert SECRET not in log
    assert f"WebSocket {API}/live/ws?token=***" in log  # logged, and redacted
    assert "GET /live?token=***" in log


def test_the_log_filter_redacts_every_kind_of_token() -> None:
    """In process: the filter ``camd serve`` puts on its log handlers, on records of every
    shape (arguments, an exception's traceback, a cookie, a Bearer header)."""
    stream = io.StringIO()
    handler = logging.StreamHandler(stream)
    handler.addFilter(RedactSecrets("hunter22"))
    logger = logging.getLogger("test_http_edges.redact")
    logger.addHandler(handler)
    logger.propagate = False
    try:
        logger.warning(
            '%s - "WebSocket %s" [accepted]', "127.0.0.1:5", "/api/v1/live/ws?token=a%2Fb"
        )
        logger.warning("GET /live?client=me&token=xyz&x=1 HTTP/1.1")
        logger.warning("headers: Authorization: Bearer abc.def-ghi, Cookie: camd_token=qq; a=b")
        logger.warning("the token is %s", "hunter22")
        try:
            raise ValueError("bad url http://h/?token=in-a-traceback")
        except ValueError:
            logger.exception("failed")
    finally:
        logger.removeHandler(handler)
    text = stream.getvalue()
    for secret in ("a%2Fb", "xyz", "abc.def", "qq", "hunter22", "in-a-traceback"):
        assert secret not in text, text
    assert text.splitlines()[:4] == [
        '127.0.0.1:5 - "WebSocket /api/v1/live/ws?token=***" [accepted]',
        "GET /live?client=me&token=***&x=1 HTTP/1.1",
        "headers: Authorization: Bearer ***, Cookie: camd_token=***; a=b",
        "the token is ***",
    ]
    assert "ValueError: bad url http://h/?token=***" in text


def test_allowed_origins_must_be_origins() -> None:
    config = config_from_dict(
        {"api": {"allowed_origins": ["HTTP://Lab-PC:8080/", "https://x:443"]}}
    )
    assert config.api.allowed_origins == ["http://lab-pc:8080", "https://x"]
    for bad, why in (
        ("lab-pc:8080", "is not an origin (http or https and a host)"),
        ("http://lab-pc/live", "has more than scheme, host and port"),
        ("http://lab-pc:99999", "is not an origin;"),
    ):
        with pytest.raises(ConfigError) as refused:
            config_from_dict({"api": {"allowed_origins": [bad]}}, source="camd.toml")
        assert f"camd.toml: api.allowed_origins: {bad!r} {why}" in str(refused.value)
        assert "e.g. http://lab-pc:8080" in str(refused.value)


# -- the emergency stop from a shell --------------------------------------------------------


def test_an_emergency_stop_from_a_shell_is_never_refused(tmp_path: Path, daemon: Daemon) -> None:
    """``curl -X POST http://127.0.0.1:8422/api/v1/estop``: no Origin, no X-Camd-Client, no body
    (httpx adds nothing either). Last in the module: it stops the camera's stage."""
    for path in (f"{API}/motion/stop", f"{API}/estop", f"{API}/motion/estop"):
        with daemon.raw() as sock:
            sock.sendall(
                f"POST {path} HTTP/1.1\r\nHost: {daemon.host}:{daemon.port}\r\n"
                "Content-Length: 0\r\nConnection: close\r\n\r\n".encode()
            )
            status, _, body = _read_response(sock)
        assert status == 200, body
