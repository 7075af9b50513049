"""A second camera, built from the documents alone (issue 31: "documents complete enough to
build a device from").

Written from docs/protocol.md, docs/motion.md, docs/wheel.md, docs/sensors.md and the data
files a vendor gets (config/protocol.toml, config/sensors/*.toml, config/stages/*.toml,
config/wheel.toml), never from camd's code or the simulator in firmware_models/: this package
imports neither (tests/test_doc_device.py checks its imports). Where a document left something
to guess, the guess was replaced by a statement in the document, and the statement is
implemented here as written, so this device, the simulator and the documents agree
(tests/test_doc_device.py).

- ``wire``: frames, CRC, the receiver's resynchronisation, payloads laid out by the dictionary.
- ``device``: the command processor (mode, fault, registers, training, stage, wheel).
- ``server``: the device behind a real pseudo-terminal, as a serial port to the daemon.
"""
