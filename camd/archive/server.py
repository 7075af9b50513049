"""``camd archive serve``: a Tiled server over a camd data directory (docs/archive.md).

Order of events: check the data directory and the key (exit 2), bind the socket (exit 2 if the
port is taken), make the catalogue if it is new and index the data directory into it (a
separate catalogue connection, closed before serving), build Tiled's app over the catalogue
with its single-user API key (or anonymous reading with ``--public``), then print one line on
stdout, ``camd archive serving http://HOST:PORT/api/v1/``, and serve until SIGINT or SIGTERM.
``camd archive index`` (another process) adds the files written since.

The key is never printed nor logged: the log handlers pass every record through the daemon's
``RedactSecrets`` with the key, which replaces it (in a URL's ``?api_key=`` or a header alike)
with ``***``.
"""

from __future__ import annotations

import asyncio
import logging
import os
import secrets
import signal
import stat
import sys
from pathlib import Path
from types import FrameType

from camd.archive.catalogue import index, init_catalogue, open_catalogue
from camd.daemon.serve import RedactSecrets, bind_listening_socket, url_host

__all__ = ["API_KEY_ENV", "ArchiveError", "api_key", "check_data_dir", "index_once", "serve"]

log = logging.getLogger("camd.archive")

API_KEY_ENV = "TILED_SINGLE_USER_API_KEY"  # Tiled's own name for the single-user key
API_PATH = "/api/v1/"
# What a camd data directory holds once a daemon has used it (camd.daemon.output_paths,
# camd.daemon.config): one of them tells it from a directory given by mistake.
DATA_DIR_MARKS = ("recordings", "scans", "campaigns", "telemetry.sqlite")


class ArchiveError(Exception):
    """A bad argument or state the user fixes; the message says what to change."""


def check_data_dir(data_dir: Path) -> Path:
    """``data_dir`` resolved, or ArchiveError saying why it is not a camd data directory."""
    if not data_dir.exists():
        raise ArchiveError(
            f"the data directory {data_dir} does not exist; give the daemon's data directory "
            "(daemon.data_dir in its config, docs/config.md)"
        )
    if not data_dir.is_dir():
        raise ArchiveError(
            f"{data_dir} is not a directory; give the daemon's data directory "
            "(daemon.data_dir in its config, docs/config.md)"
        )
    if not any((data_dir / mark).exists() for mark in DATA_DIR_MARKS):
        raise ArchiveError(
            f"{data_dir} is not a camd data directory: it holds none of "
            f"{', '.join(DATA_DIR_MARKS)}; give the daemon's data directory "
            "(daemon.data_dir in its config, docs/config.md)"
        )
    return data_dir.resolve()


def api_key(key_file: Path) -> tuple[str, str]:
    """The single-user API key and where it came from: ``$TILED_SINGLE_USER_API_KEY`` if set,
    else ``key_file``, made with a new random key (owner-only, 0600) if it does not exist."""
    from_env = os.environ.get(API_KEY_ENV)
    if from_env:
        where = f"${API_KEY_ENV}"
        key = from_env
    else:
        where = str(key_file)
        if not key_file.exists():
            key_file.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(key_file, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
            with os.fdopen(fd, "w", encoding="ascii") as out:
                out.write(secrets.token_hex(32) + "\n")
        mode = stat.S_IMODE(key_file.stat().st_mode)
        if mode & 0o077:
            raise ArchiveError(
                f"the API key file {key_file} may be read by others (mode {mode:o}): "
                f"chmod 600 {key_file}"
            )
        key = key_file.read_text(encoding="ascii").strip()
    if not key.isalnum():
        raise ArchiveError(
            f"the API key in {where} must be letters and digits only (Tiled's rule): make a "
            "new one, e.g. `python -c 'import secrets; print(secrets.token_hex(32))'`"
        )
    return key, where


async def index_once(uri: str, data_dir: Path) -> str:
    """Index ``data_dir`` into the catalogue at ``uri`` through a connection of its own; the
    summary line, the files skipped logged with why."""
    catalogue = open_catalogue(uri, data_dir)
    await catalogue.startup()
    try:
        report = await index(catalogue, data_dir)
    finally:
        await catalogue.shutdown()
    for relative, why in report.skipped:
        log.warning("skipped %s: %s", relative, why)
    return report.summary()


def serve(
    data_dir: Path,
    uri: str,
    *,
    host: str,
    port: int,
    key: str,
    public: bool,
) -> int:
    """Index, then serve until SIGINT or SIGTERM (module docstring); the exit status."""
    import uvicorn
    from tiled.config import Authentication
    from tiled.server.app import build_app

    try:
        sock = bind_listening_socket(host, port)
    except OSError as exc:
        raise ArchiveError(
            f"cannot listen on {host}:{port}: {exc.strerror or exc}; stop what uses the port "
            "or choose another with --port"
        ) from None
    init_catalogue(uri)
    log.info("indexed %s: %s", data_dir, asyncio.run(index_once(uri, data_dir)))
    app = build_app(
        open_catalogue(uri, data_dir),
        Authentication(allow_anonymous_access=public, single_user_api_key=key),
    )
    # log_config None: uvicorn's records go to the root handlers, which redact the key.
    server = uvicorn.Server(uvicorn.Config(app, log_config=None, access_log=True))

    def stop(signum: int, frame: FrameType | None) -> None:
        server.should_exit = True

    # uvicorn takes SIGINT and SIGTERM over while it serves, and raises the one it caught again
    # once it has stopped, under the handlers it found: these, so that a stop exits 0.
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, stop)

    async def run() -> None:
        bound_host, bound_port = sock.getsockname()[:2]
        print(f"camd archive serving http://{url_host(bound_host)}:{bound_port}{API_PATH}",
              flush=True)  # fmt: skip
        await server.serve(sockets=[sock])

    asyncio.run(run())
    return 0


def setup_logging(key: str) -> None:
    """Everything on stderr (stdout carries only the ``serving`` line), the key redacted."""
    logging.basicConfig(
        level=logging.INFO,
        stream=sys.stderr,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    for handler in logging.getLogger().handlers:
        handler.addFilter(RedactSecrets(key))
