"""The simulated camera: it stands where the hardware stands.

Imports only camd's pure layers (camd.protocol, camd.timing, and the register-map data of
camd.sensor: regmap, spi_frame, timing_view), never its stateful ones.

- ``firmware_models.fpga.FpgaModel``: the FPGA's command processor (sans-I/O)
- ``firmware_models.housekeeping.HousekeepingModel``: temperatures, supplies, uptime
- ``firmware_models.inject``: ``InjectSpec`` (the ``--inject`` contract) and ``FaultInjector``
- ``firmware_models.pty_server.PtyServer``: the model behind a real pseudo-terminal
- ``firmware_models.sensor.SensorModel``: the image sensor's register file
- ``firmware_models.spi``: SPI master and slave at the bit level (CPOL/CPHA)
- ``firmware_models.sensor_link.SensorLink``: the FPGA's LVDS training and capture path
- ``firmware_models.lvds``: skewed LVDS lanes, deserializer, training algorithm, test patterns
- ``firmware_models.sequencer``: the HR400 rolling-shutter row address sequence
- ``firmware_models.usb_device``: the simulated-USB-device base of the pyusb backends
- ``firmware_models.mcp2210_backend``: host half of the MCP2210 USB-SPI bridge, loaded by the
  daemon: the chip model as a pyusb backend and the client end of the SPI socket;
  ``firmware_models.usb_spi``: its device half, the simulator's SPI socket server;
  ``firmware_models.spi_wire``: that socket's framing
- ``firmware_models.fx3_backend``: host half of the EZ-USB FX3 frame streamer, loaded by the
  daemon: the pyusb backend reading the stream socket; ``firmware_models.fx3``: its device half,
  the socket server and stream engine (pacing, frame faults); ``firmware_models.fx3_wire``:
  that socket's framing
- ``firmware_models.camera.CameraModel``: window frames from the scene and the sensor physics
- ``firmware_models.scene``: scenes (flat, bars, edge, star, ramp, image) and exact motion
  integration; ``firmware_models.stage``: the simulated scan stage
- ``firmware_models.imaging.ImagingPipeline``: camera -> LVDS -> binning -> header -> stream
- ``firmware_models.cli.main``: ``python -m firmware_models`` / ``camd sim``
"""
