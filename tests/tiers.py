"""The fast tier: tests that start no process, selected with ``pytest -m "not daemon"``.

A test is marked ``daemon`` when the code it runs can start a process: a camd daemon
(``DaemonProcess``, ``start_sim_daemon``), the simulated camera, a browser, ``camd`` or
``camctl``, or any other command. The mark is found, not written by hand: at collection each
test's function and the fixtures it uses are read (their code's global names, and the tests' and
camd's own functions and classes those name, followed down), and a test that reaches
``subprocess``, ``multiprocessing``, Playwright or one of ``os``'s process calls is marked. A test
may also carry ``@pytest.mark.daemon`` itself.

The finding is checked while the tests run: an audit hook (``sys.addaudithook``) sees every
process the interpreter starts, and a test outside the mark that starts one fails, naming the
process, so the fast tier cannot quietly start daemons. (Code that starts a process through a
path the reading cannot follow, e.g. a method called on an object, is caught there; mark such a
test ``daemon`` by hand.)
"""

from __future__ import annotations

import importlib
import sys
import types
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import pytest

MARK = "daemon"

# Modules whose use starts a process, and os's functions that do.
PROCESS_MODULES = frozenset({"subprocess", "multiprocessing", "playwright.sync_api"})
OS_PROCESS_CALLS = frozenset(
    {"fork", "forkpty", "posix_spawn", "posix_spawnp", "system", "popen", "spawnv", "spawnvp"}
    | {"execv", "execve", "execvp", "execvpe", "execl", "execlp"}
)
# The audit events of a new process (docs.python.org, "Audit events table").
PROCESS_EVENTS = frozenset(
    {"subprocess.Popen", "os.posix_spawn", "os.fork", "os.forkpty", "os.system", "os.spawn"}
    | {"os.exec"}
)
# Processes a library starts to look something up, not the test: ctypes.util.find_library (pyusb
# finding libusb) runs `ldconfig -p`, platform.uname() (a library's import) `uname -p`.
LOOKUP_COMMANDS = frozenset({"/sbin/ldconfig", "ldconfig", "uname"})
# Only this code is read; a library's is taken as it is (its processes are the guard's to see).
OWN_PACKAGES = ("tests", "camd", "firmware_models", "conftest", "test_")


def _own(obj: Any) -> bool:
    module = getattr(obj, "__module__", None) or ""
    return module.startswith(OWN_PACKAGES)


class _Reader:
    """Follows a function's global names down to a process start; remembers what it read."""

    def __init__(self) -> None:
        self._known: dict[int, tuple[str, ...] | None] = {}  # final answers
        self._seen: set[int] = set()  # read in the current search

    def path_to_process(self, obj: Any) -> tuple[str, ...] | None:
        """The names from ``obj`` down to what starts a process, or None if none is reached."""
        self._seen = set()
        found = self._search(obj)
        if found is None:  # nothing the search read reaches a process
            self._known.update(dict.fromkeys(self._seen))
        return found

    def _search(self, obj: Any) -> tuple[str, ...] | None:
        # Depth first, each object once per search. A "no" inside a search may only mean that
        # the object led back to one being read, so it is kept only when the whole search
        # says no; a path found is a path.
        key = id(obj)
        if key in self._known:
            return self._known[key]
        if key in self._seen:
            return None
        self._seen.add(key)
        found = self._read(obj)
        if found is not None:
            self._known[key] = found
        return found

    def _read(self, obj: Any) -> tuple[str, ...] | None:
        if isinstance(obj, types.ModuleType):
            return (obj.__name__,) if obj.__name__ in PROCESS_MODULES else None
        obj = getattr(obj, "__wrapped__", obj)  # contextmanager, functools.wraps
        if isinstance(obj, (staticmethod, classmethod)):
            obj = obj.__func__
        if isinstance(obj, types.MethodType):
            obj = obj.__func__
        if isinstance(obj, type):
            if not _own(obj):
                return None
            for member in vars(obj).values():
                below = self._search(member)
                if below is not None:
                    return below
            return None
        if isinstance(obj, types.FunctionType) and _own(obj):
            below = self._read_code(obj.__code__, obj.__globals__)
            return (obj.__qualname__, *below) if below is not None else None
        return None

    def _read_code(self, code: types.CodeType, names: dict[str, Any]) -> tuple[str, ...] | None:
        # The names a code uses (co_names: its globals, attributes and imported modules), read
        # as globals where the module has one of the name: an attribute named as a global may
        # mark a test that starts nothing, never miss one (and reading the bytecode instead
        # cost 2 s of every collection).
        used = set(code.co_names)
        modules: list[types.ModuleType] = []
        for name in sorted(used):
            if name in PROCESS_MODULES:  # a local import of one
                return (name,)
            if name in names:
                value = names[name]
            elif name.startswith(OWN_PACKAGES) and "." in name:  # a local import of ours
                value = importlib.import_module(name)
            else:
                continue
            if isinstance(value, types.ModuleType):
                modules.append(value)
                continue
            below = self._search(value)
            if below is not None:
                return below
        for module in modules:
            below = self._read_module_use(module, used)
            if below is not None:
                return below
        for const in code.co_consts:
            if isinstance(const, types.CodeType):
                below = self._read_code(const, names)
                if below is not None:
                    return below
        return None

    def _read_module_use(self, module: types.ModuleType, used: set[str]) -> tuple[str, ...] | None:
        """What the names a code uses, taken from ``module`` (``module.name``, or
        ``from module import name``), reach."""
        if module.__name__ in PROCESS_MODULES:
            return (module.__name__,)
        if module.__name__ == "os":
            calls = used & OS_PROCESS_CALLS
            return (f"os.{min(calls)}",) if calls else None
        if not module.__name__.startswith(OWN_PACKAGES):
            return None
        for name in sorted(used):
            if name in vars(module):
                below = self._search(vars(module)[name])
                if below is not None:
                    return below
        return None


def starts_processes(item: pytest.Item, reader: _Reader) -> tuple[str, ...] | None:
    """How ``item`` reaches a process start (the test or a fixture, then the names down to
    it), or None."""
    function = getattr(item, "function", None)
    if function is not None:
        found = reader.path_to_process(function)
        if found is not None:
            return found
    info = getattr(item, "_fixtureinfo", None)
    for name, definitions in info.name2fixturedefs.items() if info else ():
        for definition in definitions:
            found = reader.path_to_process(definition.func)
            if found is not None:
                return (f"fixture {name}", *found[1:])
    return None


def pytest_configure(config: pytest.Config) -> None:
    guard = _Guard()
    config.stash[_GUARD] = guard
    _GUARDS.append(guard)


def pytest_unconfigure(config: pytest.Config) -> None:
    guard = config.stash.get(_GUARD, None)
    if guard in _GUARDS:
        _GUARDS.remove(guard)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    reader = _Reader()
    for item in items:
        if item.get_closest_marker(MARK) is not None:
            continue
        found = starts_processes(item, reader)
        if found is not None:
            item.add_marker(pytest.mark.daemon(reached=" -> ".join(found)))


# -- the guard ------------------------------------------------------------------------------------


@dataclass
class _Guard:
    """What the running test outside the mark started (one per pytest session; a session run
    inside a test, as pytester's, is the one that sees its own tests' processes)."""

    fast_item: str | None = None
    started: list[str] = field(default_factory=list)

    def saw(self, event: str, args: tuple[Any, ...]) -> None:
        command = _command(args)
        if self.fast_item is not None and command[:1] not in ([c] for c in LOOKUP_COMMANDS):
            text = " ".join(command)
            self.started.append(f"{event} {text if len(text) <= 160 else text[:157] + '...'}")


_GUARD = pytest.StashKey[_Guard]()
_GUARDS: list[_Guard] = []


def _command(args: tuple[Any, ...]) -> list[str]:
    """The command line in an audit event's arguments (subprocess.Popen's and os.posix_spawn's
    second argument; the path alone for os.system and the rest)."""
    if len(args) > 1 and isinstance(args[1], (list, tuple)):
        return [str(part) for part in args[1]]
    if len(args) > 1 and isinstance(args[1], (str, bytes)):  # a shell's command line
        return [str(args[1])]
    return [str(part) for part in args[:1]]


def _audit(event: str, args: tuple[Any, ...]) -> None:
    if event in PROCESS_EVENTS and _GUARDS:
        _GUARDS[-1].saw(event, args)


sys.addaudithook(_audit)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item) -> Iterator[None]:
    guard = item.config.stash.get(_GUARD, None)
    if guard is None:
        yield
        return
    guard.fast_item = item.nodeid if item.get_closest_marker(MARK) is None else None
    guard.started = []
    try:
        yield
    finally:
        guard.fast_item = None


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Iterator[None]:
    outcome = yield
    report: pytest.TestReport = outcome.get_result()
    guard = item.config.stash.get(_GUARD, None)
    if call.when != "teardown" or guard is None or not guard.started or report.failed:
        return
    started = "\n".join(f"  {what}" for what in guard.started)
    report.outcome = "failed"
    report.longrepr = (
        f"{item.nodeid} started a process but is not marked `{MARK}` (the fast tier, "
        f"-m 'not {MARK}', starts none):\n{started}\n"
        f"tests/tiers.py did not see it in the code the test runs: mark the test "
        f"@pytest.mark.{MARK}"
    )
