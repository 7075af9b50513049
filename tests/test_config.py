"""The daemon's config: defaults, validation messages, overrides, and the docs listing every key."""

from __future__ import annotations

import re
import time
from pathlib import Path
from typing import Any

import pytest
from pydantic import BaseModel

from camd.daemon.config import (
    Config,
    ConfigError,
    config_from_dict,
    default_config_path,
    load_config,
    with_overrides,
)
from camd.daemon.config_camera import DEFAULT_LIMITS, ChannelLimits, TelemetrySection
from camd.daemon.config_sections import is_loopback

DOCS = Path(__file__).resolve().parent.parent / "docs" / "config.md"
NO_ENV: dict[str, str] = {}


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "camd.toml"
    path.write_text(text)
    return path


def error_of(tmp_path: Path, text: str) -> str:
    with pytest.raises(ConfigError) as info:
        load_config(write(tmp_path, text), env=NO_ENV)
    return str(info.value)


def test_shipped_file_equals_the_model_defaults() -> None:
    # The shipped camd.toml documents the defaults; it must not drift from the code.
    assert load_config(None, env=NO_ENV) == config_from_dict({}, env=NO_ENV)
    assert default_config_path().name == "camd.toml"


def test_defaults_give_a_simulated_camera_on_loopback() -> None:
    cfg = config_from_dict({}, env=NO_ENV)
    assert cfg.link.device == "sim"
    assert (cfg.api.host, cfg.api.port, cfg.api.token) == ("127.0.0.1", 8422, "")
    assert (cfg.link.baudrate, cfg.link.timeout_s, cfg.link.retries) == (921_600, 0.1, 5)
    assert cfg.telemetry.poll_period_s == 1.0 and cfg.telemetry.red_is_fault
    assert set(cfg.telemetry.limits) == set(DEFAULT_LIMITS)
    assert cfg.sim.profile == "hr400"


def test_the_simulated_camera_gets_more_re_sends_than_a_real_one() -> None:
    # docs/config.md sim.link_retries: a process on a busy host, held back for 600 ms once.
    sim = config_from_dict({}, env=NO_ENV)
    assert (sim.sim.link_retries, sim.link_retries) == (20, 20)
    real = config_from_dict({"link": {"device": "/dev/ttyUSB0", "retries": 7}}, env=NO_ENV)
    assert real.link_retries == 7  # sim.link_retries is for the simulator only
    tuned = config_from_dict({"sim": {"link_retries": 3}}, env=NO_ENV)
    assert tuned.link_retries == 3


def test_data_dir_is_expanded_and_derived_paths_follow(tmp_path: Path) -> None:
    cfg = config_from_dict({"daemon": {"data_dir": "~/x/camd"}}, env=NO_ENV)
    assert cfg.daemon.data_dir == Path.home() / "x" / "camd"
    cfg = config_from_dict({"daemon": {"data_dir": str(tmp_path)}}, env=NO_ENV)
    assert cfg.archive_path == tmp_path / "telemetry.sqlite"
    assert cfg.sim_link_path == tmp_path / "sim" / "camera.tty"


def test_unknown_key_names_file_key_path_and_allowed_keys(tmp_path: Path) -> None:
    msg = error_of(tmp_path, "[api]\nprot = 1\n")
    assert str(tmp_path / "camd.toml") in msg
    assert "api.prot" in msg and "unknown key" in msg
    assert "host, port, token" in msg


def test_unknown_section_lists_the_sections(tmp_path: Path) -> None:
    msg = error_of(tmp_path, "[deamon]\nlog_level = 'info'\n")
    assert "deamon" in msg and "daemon, api, link, sim, sensor, stream, telemetry" in msg


def test_sensor_section_defaults_and_checks(tmp_path: Path) -> None:
    cfg = load_config(None)
    assert (cfg.sensor.name, cfg.sensor.bridge, cfg.sensor.train_on_connect) == (
        "hr400",
        "fpga",
        True,
    )
    assert (cfg.sensor.usb_spi.vendor_id, cfg.sensor.usb_spi.product_id) == (0x04D8, 0x00DE)
    msg = error_of(tmp_path, "[sensor]\nname = 'cmv4000'\n")
    assert "sensor.name: no register map for sensor 'cmv4000'; known: ftf5066, hr400, ibis5" in msg
    msg = error_of(tmp_path, "[sensor]\nbridge = 'i2c'\n")
    assert "sensor.bridge: 'i2c' is not allowed; use 'fpga' or 'usb-spi'" in msg
    # The simulated camera must carry the sensor the register map describes.
    msg = error_of(tmp_path, "[sensor]\nname = 'ibis5'\n")
    assert "sim.profile = 'hr400' but sensor.name = 'ibis5'" in msg
    ok = tmp_path / "ok.toml"
    ok.write_text("[sim]\nprofile = 'ibis5'\n[sensor]\nname = 'ibis5'\n")
    assert load_config(ok).sensor.name == "ibis5"


def test_unknown_key_inside_a_channel_limit(tmp_path: Path) -> None:
    msg = error_of(
        tmp_path, "[telemetry.limits.vcc_io_v]\nyellow = [3.2, 3.4]\nred = [3, 4]\ngreen = 1\n"
    )
    assert "telemetry.limits.vcc_io_v.green" in msg and "yellow, red" in msg


def test_out_of_range_names_the_range(tmp_path: Path) -> None:
    msg = error_of(tmp_path, "[api]\nport = 70000\n")
    assert "api.port" in msg and "70000" in msg and "0 <= port <= 65535" in msg
    msg = error_of(tmp_path, "[link]\ntimeout_s = 0\n")
    assert "link.timeout_s" in msg and "0 < timeout_s <= 60" in msg
    msg = error_of(tmp_path, "[stream]\nqueue_mb = 0\n")
    assert "stream.queue_mb" in msg and "0 < queue_mb <= 65536" in msg


def test_bad_enum_lists_the_choices(tmp_path: Path) -> None:
    msg = error_of(tmp_path, "[daemon]\nlog_level = 'loud'\n")
    assert "daemon.log_level" in msg and "'loud'" in msg and "'debug'" in msg


def test_wrong_type(tmp_path: Path) -> None:
    msg = error_of(tmp_path, "[link]\nretries = 'many'\n")
    assert "link.retries" in msg and "'many'" in msg


def test_invalid_toml_and_missing_file(tmp_path: Path) -> None:
    msg = error_of(tmp_path, "[api\n")
    assert "camd.toml" in msg and "not valid TOML" in msg
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "absent.toml")


def test_backoff_order(tmp_path: Path) -> None:
    msg = error_of(tmp_path, "[link]\nreconnect_min_s = 5\nreconnect_max_s = 1\n")
    assert "reconnect_min_s" in msg and "reconnect_max_s" in msg


@pytest.mark.parametrize("host", ["127.0.0.1", "127.3.2.1", "::1", "localhost", "[::1]"])
def test_loopback_hosts_need_no_token(host: str) -> None:
    assert is_loopback(host)
    assert config_from_dict({"api": {"host": host}}, env=NO_ENV).api.host == host


@pytest.mark.parametrize("host", ["0.0.0.0", "::", "192.168.1.20", "camera-pc.example"])
def test_remote_bind_without_token_is_refused(host: str) -> None:
    assert not is_loopback(host)
    with pytest.raises(ConfigError) as info:
        config_from_dict({"api": {"host": host}}, env=NO_ENV)
    msg = str(info.value)
    assert host in msg and "api.token" in msg and "CAMD_TOKEN" in msg


def test_remote_bind_with_a_token_from_file_or_environment() -> None:
    cfg = config_from_dict({"api": {"host": "0.0.0.0", "token": "abc"}}, env=NO_ENV)
    assert cfg.api.token == "abc"
    cfg = config_from_dict({"api": {"host": "0.0.0.0"}}, env={"CAMD_TOKEN": "xyz"})
    assert cfg.api.token == "xyz"
    # The environment wins over the file (the secret stays out of the file).
    cfg = config_from_dict({"api": {"token": "file"}}, env={"CAMD_TOKEN": "env"})
    assert cfg.api.token == "env"


def test_limits_merge_over_defaults() -> None:
    cfg = config_from_dict(
        {"telemetry": {"limits": {"fpga_temp_degc": {"yellow": [10, 60], "red": [0, 80]}}}},
        env=NO_ENV,
    )
    assert cfg.telemetry.limits["fpga_temp_degc"] == ChannelLimits(yellow=(10, 60), red=(0, 80))
    assert cfg.telemetry.limits["vcc_io_v"] == DEFAULT_LIMITS["vcc_io_v"]


def test_limit_channel_must_exist_in_housekeeping(tmp_path: Path) -> None:
    msg = error_of(tmp_path, "[telemetry.limits.cpu_temp]\nyellow = [0, 1]\nred = [0, 2]\n")
    assert "cpu_temp" in msg and "fpga_temp_degc" in msg and "HOUSEKEEPING" in msg


@pytest.mark.parametrize(
    ("yellow", "red", "words"),
    [
        ([0, 5], [1, 6], "must contain yellow"),
        ([0, 5], [-1, 4], "must contain yellow"),
        ([5, 0], [-1, 6], "lo > hi"),
        ([0, 5], [6, -1], "lo > hi"),
    ],
)
def test_red_must_contain_yellow(
    tmp_path: Path, yellow: list[float], red: list[float], words: str
) -> None:
    msg = error_of(tmp_path, f"[telemetry.limits.vcc_io_v]\nyellow = {yellow}\nred = {red}\n")
    assert "telemetry.limits.vcc_io_v" in msg and words in msg


def test_equal_ranges_are_allowed() -> None:
    assert ChannelLimits(yellow=(1, 2), red=(1, 2)).red == (1, 2)


def test_overrides_are_revalidated() -> None:
    cfg = config_from_dict({}, env=NO_ENV)
    changed = with_overrides(cfg, {"api.port": 0, "link.device": "/dev/ttyUSB0"})
    assert changed.api.port == 0 and changed.link.device == "/dev/ttyUSB0"
    assert with_overrides(cfg, {"api.port": None}) == cfg  # unset flags change nothing
    with pytest.raises(ConfigError, match=r"0\.0\.0\.0.*api\.token"):
        with_overrides(cfg, {"api.host": "0.0.0.0"})
    with pytest.raises(ConfigError, match=r"api\.port"):
        with_overrides(cfg, {"api.port": -1})


def _keys(model: type[BaseModel], prefix: str) -> list[str]:
    """Every documented key path of ``model`` (channel limits as ``<channel>``)."""
    out = []
    for name, field in model.model_fields.items():
        path = f"{prefix}{name}"
        annotation: Any = field.annotation
        if isinstance(annotation, type) and issubclass(annotation, BaseModel):
            out += _keys(annotation, path + ".")
        else:
            out.append(path)
            if model is TelemetrySection and name == "limits":
                out += _keys(ChannelLimits, path + ".<channel>.")
    return out


def test_every_key_is_documented() -> None:
    docs = DOCS.read_text()
    keys = _keys(Config, "")
    assert len(keys) >= 20
    missing = [k for k in keys if f"`{k}`" not in docs]
    assert not missing, f"docs/config.md does not document: {missing}"


def test_every_key_is_in_the_shipped_file() -> None:
    shipped = default_config_path().read_text()
    for key in _keys(Config, ""):
        leaf = key.rsplit(".", 1)[-1]
        if "<channel>" in key or key == "telemetry.limits":
            continue
        # A key whose default is "absent" (None) is shown commented out: TOML has no null.
        assert re.search(rf"^(# )?{leaf} = ", shipped, re.M), f"config/camd.toml lacks {key}"


def test_simulator_sockets_move_out_of_a_deep_data_dir(tmp_path: Path) -> None:
    """A Unix socket's path must fit sun_path (108 bytes on Linux): a deep data directory's
    sockets go to a short directory of their own in the temp dir, the same for the same dir."""
    short = config_from_dict({"daemon": {"data_dir": str(tmp_path / "d")}}, env=NO_ENV)
    assert short.sim_spi_socket == tmp_path / "d" / "sim" / "spi.sock"
    deep_dir = tmp_path / ("x" * 60) / ("y" * 60)
    deep = config_from_dict({"daemon": {"data_dir": str(deep_dir)}}, env=NO_ENV)
    for sock in (deep.sim_spi_socket, deep.sim_usb_socket):
        assert len(str(sock).encode()) <= 100 and sock.parent.name.startswith("camd-sim-")
    again = config_from_dict({"daemon": {"data_dir": str(deep_dir)}}, env=NO_ENV)
    assert again.sim_socket_dir == deep.sim_socket_dir
    other = config_from_dict({"daemon": {"data_dir": str(deep_dir / "z")}}, env=NO_ENV)
    assert other.sim_socket_dir != deep.sim_socket_dir


def test_tdi_warm_up_from_the_file_or_the_environment() -> None:
    assert config_from_dict({}, env={}).daemon.tdi_warm_up is True  # as shipped
    assert config_from_dict({}, env={"CAMD_TDI_WARM_UP": "0"}).daemon.tdi_warm_up is False
    on = config_from_dict({"daemon": {"tdi_warm_up": False}}, env={"CAMD_TDI_WARM_UP": "1"})
    assert on.daemon.tdi_warm_up is True  # the environment wins over the file
    with pytest.raises(ConfigError, match=r"CAMD_TDI_WARM_UP='yes': give 0 or 1"):
        config_from_dict({}, env={"CAMD_TDI_WARM_UP": "yes"})


def test_a_daemon_with_the_warm_up_loads_the_tdi_kernels_at_start(tmp_path: Path) -> None:
    """The shipped default, which the rest of the suite turns off (tests/conftest.py)."""
    from camd.cli._daemon_proc import DaemonProcess
    from camd.client import CamdClient

    with DaemonProcess(tmp_path, env={"CAMD_TDI_WARM_UP": "1"}) as daemon:
        with CamdClient(daemon.url) as client:
            client.wait_ready(60.0)
        deadline = time.monotonic() + 120.0
        while "TDI kernels ready in" not in daemon.log_path.read_text():
            assert time.monotonic() < deadline, daemon.log_path.read_text()[-2000:]
            time.sleep(0.1)
    cold = tmp_path / "cold"
    with (
        DaemonProcess(cold, env={"CAMD_TDI_WARM_UP": "0"}) as daemon,
        CamdClient(daemon.url) as client,
    ):
        client.wait_ready(60.0)
    assert "TDI kernels" not in (cold / "daemon.log").read_text()


# -- issue 31: config and data files strict about types, file:line errors, no traceback --------

CONFIG_ROWS = [
    # (camd.toml text, the whole error)
    ('[api]\nport = "8423"\n',
     "{file}:2: api.port: '8423' is a string, the wrong type; write an integer, without quotes"),
    ("[daemon]\n\n[sim]\nhk_period_s = true\n",
     "{file}:4: sim.hk_period_s: True is a boolean, the wrong type; write a number, without "
     "quotes"),
    ('[telemetry.limits.vcc_io_v]\nyellow = [3.2, 3.4]\nred = [3, "4"]\n',
     "{file}:3: telemetry.limits.vcc_io_v.red.1: '4' is a string, the wrong type; write a "
     "number, without quotes"),
    ('[sim]\nscene = "' + "z" * 1_000_000 + '"\n',
     "{file}:2: sim.scene: String should have at most 240 characters (got '" + "z" * 79
     + "... (1000002 characters))"),
    ('[sim]\nprofile = "hr401"\n',
     "{file}:2: sim.profile: no camera profile 'hr401' (config/profiles/); give one of "
     "ftf5066, hr400, ibis5, mt9m001, uvccd"),
]  # fmt: skip


@pytest.mark.parametrize(
    ("text", "error"),
    CONFIG_ROWS,
    ids=["port-string", "bool-for-number", "limit-string", "megabyte-scene", "sim-profile"],
)
def test_camd_toml_is_strict_and_names_the_line(tmp_path: Path, text: str, error: str) -> None:
    assert error_of(tmp_path, text) == error.format(file=tmp_path / "camd.toml")


def _broken_copy(tmp_path: Path, file: str, old: str, new: str) -> Path:
    """camd, its simulator and config/ copied to ``tmp_path`` (run from there, they read that
    config/), with ``old`` replaced by ``new`` once in ``config/<file>``."""
    import shutil

    root = Path(__file__).resolve().parents[1]
    for name in ("camd", "firmware_models", "config"):
        shutil.copytree(root / name, tmp_path / name,
                        ignore=shutil.ignore_patterns("__pycache__", "_data"))  # fmt: skip
    path = tmp_path / "config" / file
    text = path.read_text(encoding="utf-8")
    assert old in text
    path.write_text(text.replace(old, new, 1), encoding="utf-8")
    return tmp_path


BROKEN_FILES = [
    # (file, text replaced, by, the error's start, what it says)
    ("profiles/hr400.toml", "\ncolumns = ", "\ncolums = ", "config/profiles/hr400.toml:15: ",
     "colums: unknown key; did you mean `columns`?; known keys: profile, "),
    ("profiles/hr400.toml", "\ncolumns = ", "\n# columns = ", "config/profiles/hr400.toml: ",
     'columns: missing key; add `columns = { value = ..., source = "..." }`'),
    ("profiles/hr400.toml", "columns = { value = 2048,", 'columns = { value = "2048",',
     "config/profiles/hr400.toml:15: ",
     "columns.value: '2048' is a string, the wrong type; write an integer, without quotes"),
    ("protocol.toml", "opcode = 0x01", "opcod = 0x01", "config/protocol.toml:78: ",
     "command PING: opcod: unknown key; did you mean `opcode`?"),
    ("protocol.toml", "opcode = 0x01", 'opcode = "0x01"', "config/protocol.toml:78: ",
     "command PING: opcode: '0x01' is a string, the wrong type; write an integer, without "
     "quotes"),
]  # fmt: skip


@pytest.mark.parametrize(("file", "old", "new", "where", "what"), BROKEN_FILES,
                         ids=["profile-typo", "profile-missing-key", "profile-string-columns",
                              "protocol-typo", "protocol-opcode-string"])  # fmt: skip
def test_a_broken_data_file_stops_the_simulator_and_daemon_with_file_line_no_traceback(
    tmp_path: Path, file: str, old: str, new: str, where: str, what: str
) -> None:
    """issue 31: 22 lines of simulator traceback (a profile), 44 of raw pydantic text
    (protocol.toml); now one line each that says where and what to change, exit status 2."""
    import subprocess
    import sys

    root = _broken_copy(tmp_path / "tree", file, old, new)
    data = tmp_path / "data"
    for argv in ([sys.executable, "-m", "firmware_models", "--profile", "hr400"],
                 [sys.executable, "-m", "camd", "serve", "--sim", "--port", "0",
                  "--data-dir", str(data)]):  # fmt: skip
        proc = subprocess.run(argv, cwd=root, capture_output=True, text=True, timeout=120,
                              env={"PATH": "/usr/bin:/bin", "PYTHONPATH": str(root)},
                              check=False)  # fmt: skip
        assert proc.returncode == 2, (argv, proc.stderr)
        assert "Traceback" not in proc.stderr, proc.stderr
        line = next(x for x in proc.stderr.splitlines() if f"{root}/{where}" in x)
        assert f"{root}/{where}{what}" in line, proc.stderr
