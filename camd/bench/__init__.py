"""``camd bench``: the benchmarks, the API fuzzer and their support (bench/README.md).

Apart from the user's commands (``camd.cli``): these measure camd, they do not run a camera.
``camd`` (``camd.cli.camd_main``) imports ``camd.bench.command`` only when ``camd bench`` runs.

- ``command``: the ``camd bench`` subcommand, one sub-subcommand per module below;
- ``ping``, ``stream``, ``tdi``, ``scan``, ``pipeline``, ``sim``, ``live``: one benchmark each,
  a ratio against a baseline measured in the same run; ``run_all``: ``camd bench all``, every
  benchmark in its own process and one document of their ratios;
- ``fuzz``: ``camd bench fuzz``, the API fuzzed from its own /openapi.json (also the driver of
  tests/test_fuzz_api.py), with ``device_snapshot``, the device's state before and after a
  refused request (also used by the tests);
- ``common``: what the benchmarks share (the machine, its cache, A/B alternation, /proc
  readers; ``camd soak`` reads /proc with it too); ``streamer``: the simulated FX3 in its own
  process, the unpaced source of ``stream`` and ``pipeline``.

The daemons they measure are started with ``camd.cli._daemon_proc``, which the user's commands
(``camd demo``, ``camd conform``, ``camctl campaign run --sim``) use too, so it stays in
``camd.cli`` and this package sits above it.
"""
