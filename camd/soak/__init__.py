"""``camd soak``: long workloads against a daemon it starts, counted, not timed (docs/cli.md).

Apart from the user's commands (``camd.cli``): a soak checks camd over minutes to hours, it does
not run a camera. ``camd`` (``camd.cli.camd_main``) imports ``camd.soak.command`` only when
``camd soak`` runs.

- ``command``: the ``camd soak`` subcommand, its options and the printed figures and verdicts;
- ``workload``: the mixed workload on a lossy simulated line (``Soak``) and what it counts;
- ``edges``: ``camd soak --edges``, a data disk filled and emptied under campaign jobs and
  emergency stops (``EdgeSoak``), with the tmpfs helpers the crash tests use too
  (tests/crash_support.py).

It starts its daemon with ``camd.cli._daemon_proc`` (the user's commands use it too), finds the
shipped campaigns as ``camctl campaign`` does (``camd.cli.camctl_campaign``), and reads a
process's /proc status with the benchmarks' reader (``camd.bench.common``): it sits above both.
"""
