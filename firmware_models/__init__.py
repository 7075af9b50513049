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
- ``firmware_models.usb_spi``: the MCP2210 USB-SPI bridge as a pyusb backend, SPI socket
- ``firmware_models.fx3``: the EZ-USB FX3 frame streamer as a pyusb backend, its socket and
  stream engine (pacing, frame faults)
- ``firmware_models.camera.CameraModel``: window frames from the scene and the sensor physics
- ``firmware_models.scene``: scenes (flat, bars, edge, star, ramp, image) and exact motion
  integration; ``firmware_models.stage``: the simulated scan stage
- ``firmware_models.imaging.ImagingPipeline``: camera -> LVDS -> binning -> header -> stream
- ``firmware_models.cli.main``: ``python -m firmware_models`` / ``camd sim``
"""
