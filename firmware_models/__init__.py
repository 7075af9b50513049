"""The simulated camera: it stands where the hardware stands.

Imports only camd's pure layers (camd.protocol, later camd.timing), never its stateful ones.

- ``firmware_models.fpga.FpgaModel``: the FPGA's command processor (sans-I/O)
- ``firmware_models.housekeeping.HousekeepingModel``: temperatures, supplies, uptime
- ``firmware_models.inject``: ``InjectSpec`` (the ``--inject`` contract) and ``FaultInjector``
- ``firmware_models.pty_server.PtyServer``: the model behind a real pseudo-terminal
- ``firmware_models.cli.main``: ``python -m firmware_models`` / ``camd sim``
"""
