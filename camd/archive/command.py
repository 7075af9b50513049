"""``camd archive``: serve a camd data directory through Tiled, and keep its catalogue current.

``camd archive serve DATA_DIR`` indexes the directory's recordings and scans into a catalogue
(an SQLite file, ``DATA_DIR/archive/catalog.db``, unless ``--catalog`` names another, e.g. a
PostgreSQL database) and serves it with Tiled; ``camd archive index DATA_DIR`` brings the same
catalogue up to date with the files written since (the server need not stop). Tiled is an
optional dependency (``pip install 'camd[archive]'``): this module imports it only when a
command runs, so that ``camd --help`` works without it. docs/archive.md says the rest.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path

DEFAULT_PORT = 8423  # beside the daemon's 8422
ARCHIVE_FOLDER = "archive"  # in the data directory: the default catalogue and key file
CATALOGUE_FILE = "catalog.db"
KEY_FILE = "api_key"
EXIT_USAGE = 2


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "archive",
        help="serve a data directory's recordings and scans through Tiled (docs/archive.md)",
        description="Serve a camd data directory's recordings and scans through Tiled, "
        "searchable by their metadata, and keep its catalogue up to date. Needs the optional "
        "extra: pip install 'camd[archive]'.",
    )
    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    for name, text in (
        ("serve", "index DATA_DIR, then serve it with Tiled until Ctrl-C"),
        ("index", "add new and changed files to the catalogue, remove those gone"),
    ):
        action = actions.add_parser(name, help=text, description=text[0].upper() + text[1:] + ".")
        action.add_argument("data_dir", type=Path, metavar="DATA_DIR",
                            help="the daemon's data directory (daemon.data_dir)")  # fmt: skip
        action.add_argument(
            "--catalog",
            metavar="URI",
            help="the catalogue: an SQLite file path or a database URI, e.g. "
            "postgresql://USER@HOST/DB (default: DATA_DIR/archive/catalog.db)",
        )
    serve = actions.choices["serve"]
    serve.add_argument("--host", default="127.0.0.1",
                       help="address to bind (default 127.0.0.1: this machine only)")  # fmt: skip
    serve.add_argument("--port", type=int, default=DEFAULT_PORT,
                       help=f"TCP port (default {DEFAULT_PORT}; 0 picks a free one)")  # fmt: skip
    serve.add_argument(
        "--api-key-file",
        type=Path,
        metavar="FILE",
        help="file holding the API key, made with a random key if missing (default: "
        "DATA_DIR/archive/api_key; $TILED_SINGLE_USER_API_KEY overrides it)",
    )
    serve.add_argument("--public", action="store_true",
                       help="anyone who reaches the port may read, without the key")  # fmt: skip


def run(args: argparse.Namespace) -> int:
    prog = f"camd archive {args.action}"
    try:
        # Tiled is optional: say how to install it rather than show a traceback.
        import tiled  # noqa: F401
    except ImportError:
        print(f"{prog}: error: Tiled is not installed: pip install 'camd[archive]'",
              file=sys.stderr)  # fmt: skip
        return EXIT_USAGE
    from camd.archive.catalogue import CatalogueError, catalogue_uri, init_catalogue
    from camd.archive.server import (
        ArchiveError,
        api_key,
        check_data_dir,
        index_once,
        serve,
        setup_logging,
    )

    try:
        data_dir = check_data_dir(args.data_dir)
        folder = data_dir / ARCHIVE_FOLDER
        key_file = getattr(args, "api_key_file", None)  # serve only
        if args.catalog is None or (args.action == "serve" and key_file is None):
            try:
                folder.mkdir(exist_ok=True)
            except OSError as exc:
                raise ArchiveError(
                    f"cannot make {folder} for the catalogue and the key: "
                    f"{exc.strerror or exc}; give --catalog (and --api-key-file) elsewhere"
                ) from None
        uri = catalogue_uri(args.catalog or str(folder / CATALOGUE_FILE))
        if args.action == "index":
            setup_logging("")
            init_catalogue(uri)
            print(f"indexed {data_dir}: {asyncio.run(index_once(uri, data_dir))}")
            return 0
        key, where = api_key(key_file or folder / KEY_FILE)
        setup_logging(key)
        if args.public and args.host not in ("127.0.0.1", "::1", "localhost"):
            print(f"{prog}: warning: --public on {args.host}: anyone who reaches port "
                  f"{args.port} reads every file, without a key", file=sys.stderr)  # fmt: skip
        print(f"{prog}: API key in {where}" + (" (reading is public)" if args.public else ""),
              file=sys.stderr)  # fmt: skip
        return serve(data_dir, uri, host=args.host, port=args.port, key=key,
                     public=args.public)  # fmt: skip
    except (ArchiveError, CatalogueError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except OSError as exc:  # a key file that cannot be read or made
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
