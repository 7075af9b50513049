"""camd/client_requests.py: the request models' optional keys, typing the client's keyword
arguments, so that a request's defaults are written once (in the model).

- the committed file is what ``python -m camd.daemon.client_requests_gen`` renders now (that it
  passes the linters unchanged and imports nothing of camd: tests/test_client_types.py);
- ``ScanRequestOptions`` has exactly ``ScanRequest``'s optional fields, and
  ``CamdClient.start_scan`` takes its required fields and those options, with no default of its
  own. It sends only what it was given and the daemon's model fills in the rest: the scans of
  tests/test_client_types.py, test_live_lines.py and the campaign tests run on those defaults.
"""

from __future__ import annotations

import inspect
import typing
from pathlib import Path

import pytest

import camd.client_requests as client_requests
from camd.client import CamdClient
from camd.daemon.client_requests_gen import COMMAND, main, render_client_requests
from camd.daemon.models import ScanRequest

ROOT = Path(__file__).resolve().parents[1]
GENERATED = ROOT / "camd" / "client_requests.py"


def test_generated_file_is_up_to_date(capsys: pytest.CaptureFixture[str]) -> None:
    status = main(["--check"])
    assert status == 0, capsys.readouterr().err
    assert GENERATED.read_text(encoding="utf-8") == render_client_requests()


def test_check_mode_says_which_command_to_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "client_requests.py"
    assert main(["--check", "--output", str(out)]) == 1
    assert f"{out} is missing: run `{COMMAND}`" in capsys.readouterr().err
    assert main(["--output", str(out)]) == 0
    assert out.read_text(encoding="utf-8") == GENERATED.read_text(encoding="utf-8")


def test_scan_options_are_the_scan_requests_optional_fields() -> None:
    options = client_requests.ScanRequestOptions
    optional = [name for name, f in ScanRequest.model_fields.items() if not f.is_required()]
    assert list(typing.get_type_hints(options)) == optional
    assert len(optional) == 14
    assert not options.__required_keys__


def test_start_scan_writes_no_default_of_its_own() -> None:
    # CamdClient.start_scan used to repeat ScanRequest's 14 defaults by hand.
    parameters = inspect.signature(CamdClient.start_scan).parameters
    assert list(parameters) == ["self", "stages", "lines", "options"]
    assert all(p.default is inspect.Parameter.empty for p in parameters.values())
    assert parameters["options"].kind is inspect.Parameter.VAR_KEYWORD
    required = [name for name, f in ScanRequest.model_fields.items() if f.is_required()]
    assert required == ["stages", "lines"]
