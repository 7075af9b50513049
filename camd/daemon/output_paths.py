"""Where the daemon may write a file a client names: one check, before anything is made.

The daemon runs as a service on a shared machine, and any client (any local process when no
token is set) names the files it writes: a recording's ``record``, a scan's ``out``, a campaign
job's ``out`` directory. ``resolve_output`` turns such a name into the one path the daemon may
create, or refuses it with a ``BadRequest`` (400) that says why and what to give instead:

- the text: empty, a NUL byte, a control character (``\\n``, ``\\x1b``, ...), text that is not
  valid Unicode (a lone surrogate, which no file system encoding can write); a part longer than
  ``NAME_MAX_BYTES`` or a whole path longer than ``PATH_MAX_BYTES`` (the kernel's limits, which
  would otherwise fail later, half-way through the request);
- where it leads: a relative name is taken inside ``relative_to`` (a folder of the data
  directory); then ``..`` and every symbolic link, in the existing parents and the last part
  alike, are resolved, and the result must lie inside the data directory or one of the
  directories the config allows (``daemon.record_dirs``, docs/config.md). A link that loops is
  refused.

The caller writes the returned path, which has no symbolic link left, not the name it was given.
Nothing is created here: the caller's own checks (the file must be new, its directory must
exist and be writable, the disk must have room) follow, still before anything is written.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from pathlib import Path

from camd.daemon.errors import BadRequest

RECORDINGS_FOLDER = "recordings"
"""The data directory's folder where a relative ``record`` (stream, stare, wheel) goes."""
SCANS_FOLDER = "scans"
"""The data directory's folder of scans: a relative ``out`` goes here, as do unnamed scans."""
CAMPAIGNS_FOLDER = "campaigns"
"""The data directory's folder of campaign jobs: a relative ``out`` goes here."""
RECORD_DIRS_KEY = "daemon.record_dirs"
"""The config key that allows directories outside the data directory."""

NAME_MAX_BYTES = 255  # Linux NAME_MAX: the longest name of one file or directory
PATH_MAX_BYTES = 4095  # Linux PATH_MAX is 4096 bytes with the terminating NUL
SHOWN_CHARS = 240  # a refused name is quoted up to this many characters in its message

_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")  # Unicode category Cc: C0, DEL, C1
_SURROGATE = re.compile(r"[\ud800-\udfff]")


def resolve_output(
    requested: str,
    *,
    field: str,
    relative_to: Path,
    data_dir: Path,
    record_dirs: Sequence[Path] = (),
) -> Path:
    """The absolute path, free of ``..`` and symbolic links, at which the daemon may create
    what a client named ``requested`` (the request's ``field``); BadRequest saying why not and
    what to give otherwise (module docstring). A relative ``requested`` is taken inside
    ``relative_to``; the result must lie inside ``data_dir`` or one of ``record_dirs``."""
    _check_text(requested, field)
    candidate = Path(requested) if os.path.isabs(requested) else relative_to / requested
    resolved = Path(os.path.realpath(candidate))
    _check_no_link_left(resolved, requested, field)
    size = len(os.fsencode(resolved))
    if size > PATH_MAX_BYTES:
        raise BadRequest(
            f"{field} {_shown(requested)} resolves to a path of {size} bytes; the system takes "
            f"at most {PATH_MAX_BYTES} (PATH_MAX): give a shorter path"
        )
    roots = [Path(os.path.realpath(root)) for root in (data_dir, *record_dirs)]
    if not any(resolved.is_relative_to(root) for root in roots):
        lead = "is" if str(resolved) == requested else f"resolves to {_shown(str(resolved))},"
        raise BadRequest(
            f"{field} {_shown(requested)} {lead} outside the directories the daemon may "
            f"write: {_allowed(data_dir, record_dirs)}. Give a path "
            f"inside one of them, or a relative one (it goes into {relative_to}); to allow "
            f"another directory, its operator adds it to {RECORD_DIRS_KEY} in the daemon's "
            "config (docs/config.md)"
        )
    return resolved


def _check_text(requested: str, field: str) -> None:
    """Refuse what no file name can be, or should be: the checks on the text alone."""
    if not requested:
        raise BadRequest(
            f"{field} is empty: give a file name (a relative one goes into the daemon's data "
            "directory) or null"
        )
    bad = _CONTROL.search(requested)
    if bad is not None:
        char, where = bad.group(), bad.start() + 1
        what = "a NUL byte" if char == "\0" else f"the control character U+{ord(char):04X}"
        raise BadRequest(
            f"{field} {_shown(requested)} holds {what} (character {where}); file names the "
            "daemon writes hold no control characters: remove it"
        )
    bad = _SURROGATE.search(requested)
    if bad is not None:
        raise BadRequest(
            f"{field} {_shown(requested)} holds U+{ord(bad.group()):04X} (character "
            f"{bad.start() + 1}), half of a UTF-16 surrogate pair, which is not text a file "
            "name can hold: send the name as valid UTF-8"
        )
    size = len(requested.encode())
    if size > PATH_MAX_BYTES:
        raise BadRequest(
            f"{field} {_shown(requested)} is {size} bytes long; a path may be at most "
            f"{PATH_MAX_BYTES} bytes (PATH_MAX): give a shorter one"
        )
    for part in requested.split("/"):
        size = len(part.encode())
        if size > NAME_MAX_BYTES:
            raise BadRequest(
                f"{field}: the name {_shown(part)} is {size} bytes long; each part of a path "
                f"may be at most {NAME_MAX_BYTES} bytes (NAME_MAX): shorten it"
            )


def _check_no_link_left(resolved: Path, requested: str, field: str) -> None:
    """``os.path.realpath`` leaves a link that loops as it is: refuse it (the file could not be
    created, and its name says nothing about where it would go)."""
    for part in (resolved, *resolved.parents):
        # islink, not Path.is_symlink: a directory the daemon may not search is no link to it.
        if os.path.islink(part):
            raise BadRequest(
                f"{field} {_shown(requested)}: the symbolic link {part} loops (or changed "
                "while it was resolved); give a path without it"
            )


def _allowed(data_dir: Path, record_dirs: Sequence[Path]) -> str:
    """The allowed directories, for a message."""
    text = f"the data directory {data_dir}"
    if not record_dirs:
        return f"{text} (and no other: {RECORD_DIRS_KEY} is empty)"
    return f"{text} and {', '.join(str(d) for d in record_dirs)} ({RECORD_DIRS_KEY})"


def _shown(text: str) -> str:
    """``text`` quoted with its control characters escaped, cut to SHOWN_CHARS characters: a
    refused name may be long, and the error must not echo it whole."""
    if len(text) <= SHOWN_CHARS:
        return repr(text)
    return f"{text[:SHOWN_CHARS]!r}... ({len(text)} characters)"
