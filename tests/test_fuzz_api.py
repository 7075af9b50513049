"""The daemon's API fuzzed from its own /openapi.json (schemathesis), a short run.

One daemon on the simulated camera (16-row window: short frames). ``camd.bench.fuzz.fuzz``
sends requests generated from the schema to every operation, valid ones and invalid ones
alternately, with a fixed seed (reproducible): no 5xx, no hang, every answer's status code,
content type and body as documented. Every 5th refused (4xx) request to an operation that
changes something is sent again on a quiet device between two device snapshots
(``tests/device_snapshot.py``): a refusal changes nothing. At the end the daemon answers
/api/v1/status and its process lives.

Left out (``camd.bench.fuzz.EXCLUDED``, the reasons printed in a failure): POST /reset
(seconds each, undoes the rest), POST /sim/fail-next (fails the next command on purpose), POST
/link/command (sends any frame to the camera by design), POST /wheel/acquire (waits for the
wheel, seconds to minutes). Neutralised (``camd.bench.fuzz.neutralise`` / ``undo``):
acquisitions take at most 4 frames or 20 lines and write only into a scratch directory, moves
and homing return at once, an emergency stop is followed by /motion/enable, control taken is
given back, a stream or scan started is stopped. The long run is ``camd bench fuzz``.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from camd.bench.fuzz import fuzz
from camd.client import CamdClient
from tests.test_sensor_stack import serve

pytest.importorskip("schemathesis")

# Not ``exclusive``: nothing here depends on keeping up with the camera. Its acquisitions take
# at most 4 frames of a 16-row window, and a frame lost to a busy machine is counted in the
# answer, not an error; the checks are the answers' codes and bodies, a generous timeout, and
# device snapshots around refusals.

REQUESTS = 250  # about 4 per operation; the long run is `camd bench fuzz`


def test_fuzzing_the_api_finds_no_server_error_hang_or_change(tmp_path: Path) -> None:
    (tmp_path / "daemon").mkdir()
    with serve(tmp_path / "daemon", "fpga") as daemon:
        with CamdClient(daemon.url) as client:
            client.write_registers({"WIN_ROWS": 16, "EXPOSURE": 4})
        scratch = tmp_path / "files"
        scratch.mkdir()
        result = fuzz(
            daemon.url,
            requests=REQUESTS,
            seed=0,
            scratch=scratch,
            timeout_s=30.0,
            snapshot_every=5,
            alive=lambda: daemon.running,
        )
        shown = json.dumps(result, indent=1)
        assert result["requests"] == REQUESTS, shown
        assert result["operations"] >= 50 and len(result["per_operation"]) == result["operations"]
        assert result["server_errors"] == [], shown
        assert result["hangs"] == [], shown
        assert result["transport_errors"] == [], shown
        assert result["check_failures"] == {}, shown
        assert result["undo_failures"] == [], shown
        snap = result["refusals_snapshot"]
        assert snap["changed"] == [], shown
        assert snap["checked"] >= 10, shown
        assert result["alive"], shown
        with CamdClient(daemon.url) as client:
            assert client.status()["state"] in ("idle", "streaming")
    assert daemon.exit_code in (0, -15), daemon.log_path.read_text()
