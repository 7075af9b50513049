"""Where the daemon may write a file a client names (``camd.daemon.output_paths``), in-process:
one table of names against a real directory tree with symbolic links (into and out of the data
directory, a link as the last part, a loop), each resolved to the documented file or refused
with its message, and nothing created either way. tests/test_record_paths.py sends the same
names to a real daemon.
"""

from __future__ import annotations

import os
import uuid
from dataclasses import dataclass
from pathlib import Path

import pytest

from camd.daemon.config import ConfigError, config_from_dict
from camd.daemon.errors import BadRequest
from camd.daemon.output_paths import (
    NAME_MAX_BYTES,
    PATH_MAX_BYTES,
    RECORDINGS_FOLDER,
    resolve_output,
)

NEVER = f"camd-test-{uuid.uuid4().hex}.h5"  # a name no run leaves behind


@dataclass(frozen=True)
class Tree:
    """data/ (the data directory), allowed/ (daemon.record_dirs), outside/, and links."""

    root: Path
    data: Path
    allowed: Path
    outside: Path


def make_tree(root: Path) -> Tree:
    data, allowed, outside = root / "data", root / "allowed", root / "outside"
    for folder in (data / RECORDINGS_FOLDER, data / "sub", allowed, outside, root / "data-evil"):
        folder.mkdir(parents=True)
    (data / "link_in").symlink_to(data / "sub")  # a directory link that stays inside
    (data / "link_out").symlink_to(outside)  # ... and one that leads out
    (data / "final_out.h5").symlink_to(outside / "final.h5")  # the last part, leading out
    (data / "final_in.h5").symlink_to(data / "sub" / "final-target.h5")  # ... staying in
    (data / "loop_a").symlink_to(data / "loop_b")
    (data / "loop_b").symlink_to(data / "loop_a")
    return Tree(root, data, allowed, outside)


def listing(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


UP = "../" * 40  # more than any temporary directory is deep: ends at /

# (id, name with {data} {allowed} {outside} {never}, fragments of the message)
REFUSED = [
    ("etc", "/etc/{never}",
     ["record '/etc/{never}' is outside the directories the daemon may write: the data "
      "directory {data} and {allowed} (daemon.record_dirs). Give a path inside one of them, or "
      "a relative one (it goes into {data}/recordings); to allow another directory, its "
      "operator adds it to daemon.record_dirs in the daemon's config"]),
    ("root-home", "/root/{never}", ["record '/root/{never}' is outside the directories"]),
    ("dev-shm", "/dev/shm/{never}", ["record '/dev/shm/{never}' is outside the directories"]),
    ("dotdot-from-the-data-dir", "{data}/" + UP + "etc/{never}",
     ["resolves to '/etc/{never}', outside the directories the daemon may write"]),
    ("dotdot-relative", UP + "etc/{never}",
     ["resolves to '/etc/{never}', outside the directories the daemon may write"]),
    ("dotdot-to-a-sibling", "../../outside/{never}",
     ["resolves to '{outside}/{never}', outside the directories"]),
    ("outside-directory", "{outside}/{never}", ["is outside the directories"]),
    ("prefix-of-the-data-dir", "{data}-evil/{never}", ["is outside the directories"]),
    ("directory-symlink-out", "{data}/link_out/{never}",
     ["resolves to '{outside}/{never}', outside the directories"]),
    ("final-symlink-out", "{data}/final_out.h5",
     ["resolves to '{outside}/final.h5', outside the directories"]),
    ("symlink-loop", "{data}/loop_a/{never}", ["the symbolic link {data}/loop_", "loops"]),
    # Absolute names in the data directory: only the text is wrong.
    ("nul", "{data}/a\0b.h5",
     ["holds a NUL byte (character ", "file names the daemon writes hold no control "
      "characters: remove it"]),
    ("newline", "{data}/a\nb.h5", ["holds the control character U+000A", "remove it"]),
    ("escape", "{data}/\x1b[31mred.h5", ["\\x1b[31mred.h5' holds the control character U+001B"]),
    ("delete", "{data}/a\x7f.h5", ["the control character U+007F"]),
    ("c1-control", "{data}/a\x85.h5", ["the control character U+0085"]),
    ("lone-surrogate", "{data}/\ud800.h5",
     ["holds U+D800 (character ", "half of a UTF-16 surrogate pair", "valid UTF-8"]),
    ("long-component", "{data}/" + "x" * 256 + ".h5",
     ["record: the name 'xxxxxxxxxx", "... (259 characters) is 259 bytes long; each part of a "
      "path may be at most 255 bytes (NAME_MAX): shorten it"]),
    ("long-multibyte-component", "{data}/" + "é" * 128 + ".h5",
     ["is 259 bytes long", "at most 255 bytes"]),
    ("long-path", "{data}/" + "/".join(["d" * 100] * 41),
     ["bytes long; a path may be at most 4095 bytes (PATH_MAX): give a shorter one"]),
    # ... and relative ones.
    ("nul-relative", "a\0b.h5",
     ["record 'a\\x00b.h5' holds a NUL byte (character 2); file names the daemon writes hold "
      "no control characters: remove it"]),
    ("escape-relative", "\x1b[31mred.h5",
     ["record '\\x1b[31mred.h5' holds the control character U+001B (character 1)"]),
    ("long-path-relative", "/".join(["d" * 100] * 41),
     ["(4140 characters) is 4140 bytes long; a path may be at most 4095 bytes (PATH_MAX): "
      "give a shorter one"]),
    ("empty", "", ["record is empty: give a file name"]),
]  # fmt: skip

# (id, name, the file it resolves to, relative to the tree's root)
ALLOWED = [
    ("relative", "stare.h5", "data/recordings/stare.h5"),
    ("relative-in-a-folder", "sub/x.h5", "data/recordings/sub/x.h5"),
    ("relative-dotdot-staying-inside", "../sub/up.h5", "data/sub/up.h5"),
    ("absolute-in-the-data-dir", "{data}/x.h5", "data/x.h5"),
    ("allowed-extra-directory", "{allowed}/x.h5", "allowed/x.h5"),
    ("dotdot-between-allowed-dirs", "{allowed}/../data/sub/x.h5", "data/sub/x.h5"),
    ("directory-symlink-staying-inside", "{data}/link_in/x.h5", "data/sub/x.h5"),
    ("final-symlink-staying-inside", "{data}/final_in.h5", "data/sub/final-target.h5"),
    ("longest-component", "x" * (NAME_MAX_BYTES - 3) + ".h5",
     "data/recordings/" + "x" * (NAME_MAX_BYTES - 3) + ".h5"),
]  # fmt: skip


def fill(text: str, tree: Tree) -> str:
    return text.format(data=tree.data, allowed=tree.allowed, outside=tree.outside, never=NEVER)


def resolve(name: str, tree: Tree, *, field: str = "record") -> Path:
    return resolve_output(
        name,
        field=field,
        relative_to=tree.data / RECORDINGS_FOLDER,
        data_dir=tree.data,
        record_dirs=[tree.allowed],
    )


@pytest.mark.parametrize(
    ("name", "fragments"), [r[1:] for r in REFUSED], ids=[r[0] for r in REFUSED]
)
def test_a_name_the_daemon_may_not_write_is_refused_with_its_reason(
    tmp_path: Path, name: str, fragments: list[str]
) -> None:
    tree = make_tree(tmp_path)
    before = listing(tmp_path)
    with pytest.raises(BadRequest) as info:
        resolve(fill(name, tree), tree)
    message = str(info.value)
    for fragment in fragments:
        assert fill(fragment, tree) in message, message
    assert len(message) < 1200  # a long name is cut, not echoed whole
    assert listing(tmp_path) == before
    for folder in ("/etc", "/root", "/dev/shm"):
        assert not os.path.lexists(f"{folder}/{NEVER}")


@pytest.mark.parametrize(
    ("name", "expected"), [r[1:] for r in ALLOWED], ids=[r[0] for r in ALLOWED]
)
def test_a_name_inside_the_allowed_directories_resolves_to_its_file(
    tmp_path: Path, name: str, expected: str
) -> None:
    tree = make_tree(tmp_path)
    before = listing(tmp_path)
    assert resolve(fill(name, tree), tree) == tmp_path / expected
    assert listing(tmp_path) == before  # resolving creates nothing


def test_the_message_names_the_field_and_says_when_no_directory_is_allowed(tmp_path: Path) -> None:
    tree = make_tree(tmp_path)
    with pytest.raises(BadRequest) as info:
        resolve_output(
            str(tree.allowed / "x.h5"),
            field="out",
            relative_to=tree.data / "scans",
            data_dir=tree.data,
        )
    assert str(info.value) == (
        f"out '{tree.allowed}/x.h5' is outside the directories the daemon may write: the data "
        f"directory {tree.data} (and no other: daemon.record_dirs is empty). Give a path inside "
        f"one of them, or a relative one (it goes into {tree.data}/scans); to allow another "
        "directory, its operator adds it to daemon.record_dirs in the daemon's config "
        "(docs/config.md)"
    )


def test_a_data_directory_behind_a_symlink_holds_its_files(tmp_path: Path) -> None:
    tree = make_tree(tmp_path)
    (tmp_path / "via").symlink_to(tree.data)
    path = resolve_output(
        "x.h5", field="record", relative_to=tmp_path / "via" / "recordings",
        data_dir=tmp_path / "via",
    )  # fmt: skip
    assert path == tree.data / "recordings" / "x.h5"


def test_the_limits_are_the_kernels() -> None:
    assert (255, os.pathconf("/", "PC_PATH_MAX") - 1) == (NAME_MAX_BYTES, PATH_MAX_BYTES)
    assert os.pathconf("/", "PC_NAME_MAX") == NAME_MAX_BYTES


# -- daemon.record_dirs in the config ------------------------------------------------------------


def test_record_dirs_are_absolute_expanded_and_empty_by_default() -> None:
    assert config_from_dict({}, env={}).daemon.record_dirs == []
    cfg = config_from_dict({"daemon": {"record_dirs": ["/srv/camd", "~/rec"]}}, env={})
    assert cfg.daemon.record_dirs == [Path("/srv/camd"), Path.home() / "rec"]
    with pytest.raises(ConfigError) as info:
        config_from_dict({"daemon": {"record_dirs": ["/srv/camd", "rec"]}}, env={}, source="x.toml")
    assert str(info.value) == (
        "x.toml: daemon.record_dirs: entry 1 ('rec') is not an absolute path; give one starting "
        "with / (or ~)"
    )


def test_record_dirs_from_the_environment_are_added() -> None:
    env = {"CAMD_RECORD_DIRS": "/a:/b/c"}
    cfg = config_from_dict({"daemon": {"record_dirs": ["/srv"]}}, env=env)
    assert cfg.daemon.record_dirs == [Path("/srv"), Path("/a"), Path("/b/c")]
    assert config_from_dict({}, env={"CAMD_RECORD_DIRS": ""}).daemon.record_dirs == []
    with pytest.raises(ConfigError, match=r"\$CAMD_RECORD_DIRS: 'rel' is not an absolute path"):
        config_from_dict({}, env={"CAMD_RECORD_DIRS": "/a:rel"})
