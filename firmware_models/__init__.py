"""The simulated camera: it stands where the hardware stands.

Imports only camd's pure layers (camd.protocol, camd.timing, and the register-map data of
camd.sensor: regmap, spi_frame, timing_view), never its stateful ones.

- ``firmware_models.fpga.FpgaModel``: the FPGA's command processor (sans-I/O), put together
  from the command link's device end (``fpga_link``: at-most-once execution, failures on
  purpose) and one group of command handlers per part of the camera (``fpga_control``,
  ``fpga_sensor``, ``fpga_stream``, ``fpga_motion``, ``fpga_wheel``, ``fpga_sim``; what they
  share: ``fpga_commands``)
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
  the stream engine (pacing, blocks), with its transfers (``fx3_transfers``: frame faults,
  flags, packing), its end of the socket (``fx3_socket``) and ready-made frames
  (``fx3_bank``); ``firmware_models.fx3_wire``: that socket's framing
- ``firmware_models.camera.CameraModel``: window frames from the scene and the sensor physics;
  what the registers set (``camera_settings``), the frames' making (``camera_frames``), image
  motion compensation (``camera_imc``)
- ``firmware_models.scene``: scenes (flat, bars, edge, star, ramp, image) and exact motion
  integration; ``firmware_models.stage``: the simulated scan stage (``stage_faults``,
  ``stage_segments``, ``stage_kinematics``, ``stage_history``) and ``firmware_models.motor``
  its stepper controller (``motor_profiles``, ``motor_plan``, ``motor_stall``,
  ``motor_counter``, ``motor_limits``)
- ``firmware_models.imaging.ImagingPipeline``: camera -> LVDS -> binning -> header -> stream
- ``firmware_models.cli.main``: ``python -m firmware_models`` / ``camd sim``
"""
