"""The FPGA's side of the sensor's pixel output link: training it and capturing through it.

For an LVDS sensor (HR400: 8 lanes) the FPGA must align every lane before imaging
(docs/physics.md §3): it switches the sensor to its training pattern over SPI, lets
``firmware_models.lvds_training.train`` scan the delay taps, bit-slip and shift the lanes, then switches
the sensor to a PRBS test image and counts bit errors in a captured frame to prove the result.
The sensor's test-pattern register is restored afterwards. A parallel-interface sensor needs no
training and is always ready.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from camd.sensor.regmap import FieldSpec, RegisterMap, RegisterSpec
from firmware_models.lvds import Alignment, LvdsLink
from firmware_models.lvds_training import LaneTraining, TrainingResult, train, verify
from firmware_models.spi import SpiMaster

VERIFY_ROWS = 16  # rows of the PRBS frame captured to check a training


@dataclass(frozen=True, slots=True)
class TrainingReport:
    """What TRAIN answers."""

    lanes: int
    locked_lanes: int
    locked: bool
    bit_errors: int
    verified_bits: int


class SensorLink:
    """Training state and capture path of the sensor's output link."""

    def __init__(self, regmap: RegisterMap, spi: SpiMaster, *, seed: int = 0) -> None:
        self.regmap = regmap
        self.spi = spi
        output = regmap.output
        self.lvds: LvdsLink | None = None
        self.lanes = 0
        if output.needs_training:
            self.lvds = LvdsLink(lanes=output.lanes, word_bits=output.word_bits, seed=seed)
            self.lanes = output.lanes
        self.alignment = Alignment.untrained(max(self.lanes, 1))
        self.results: list[LaneTraining] = []
        self.trained = self.lvds is None
        self._seed = seed
        self._exact = False  # capture_block: the alignment passes every bit as sent
        self._exact_for: tuple[object, ...] | None = None  # ... for this alignment key

    # -- training ---------------------------------------------------------------------------

    def train(self) -> TrainingReport:
        """Train the link as the FPGA does; the link is trained only if it locked error-free."""
        if self.lvds is None:
            return TrainingReport(0, 0, True, 0, 0)
        pattern_reg, pattern_field = self._role("test_pattern")
        word_reg, word_field = self._role("training_word")
        saved = self.spi.read(pattern_reg.address)
        try:
            self._set_pattern(pattern_reg, pattern_field, saved, "training")
            word = word_field.extract(self.spi.read(word_reg.address))
            self._seed += 1
            result = _without(train(self.lvds, word, rng_seed=self._seed), self._dark_lanes())
            self.alignment = result.alignment
            self.results = list(result.lanes)
            self._set_pattern(pattern_reg, pattern_field, saved, "prbs")
            bit_errors = verify(
                self.lvds, self.alignment, rows=VERIFY_ROWS, cols=self.regmap.columns
            )
        finally:
            self.spi.write(pattern_reg.address, saved)
        verified_bits = VERIFY_ROWS * self.regmap.columns * self.regmap.output.word_bits
        locked_lanes = sum(1 for lane in self.results if lane.locked)
        self.trained = result.locked and bit_errors == 0
        return TrainingReport(self.lanes, locked_lanes, result.locked, bit_errors, verified_bits)

    def lane(self, index: int) -> LaneTraining:
        """The last training result of one lane (an unlocked placeholder before any training)."""
        if index < len(self.results):
            return self.results[index]
        return LaneTraining(lane=index, tap=0, eye_width_taps=0, slips=0, shift=0, locked=False)

    def untrain(self) -> None:
        """Forget the alignment (FPGA reset)."""
        if self.lvds is not None:
            self.alignment = Alignment.untrained(self.lanes)
            self.results = []
            self.trained = False

    def reskew(self, seed: int) -> None:
        """New random lane skews (sensor power cycle): the link needs training again."""
        if self.lvds is not None:
            self.lvds.reskew(seed)
            self.untrain()

    def capture(self, frame: np.ndarray) -> np.ndarray:
        """The window frame as the FPGA receives it through the link's current alignment."""
        if self.lvds is None:
            return frame
        return self.lvds.receive(frame, self.alignment)

    def capture_block(self, frames: np.ndarray, max_code: int) -> np.ndarray:
        """``capture`` of each of ``frames`` (``(count, rows, cols)``, whose largest word is
        ``max_code``): the same array when the link passes every bit as sent (a parallel
        interface, or LVDS lanes trained bit-exact: ``LvdsLink.bit_exact``), else a new one."""
        if self.lvds is None:
            return frames
        key = self._alignment_key()
        if key != self._exact_for:
            self._exact = self.lvds.bit_exact(self.alignment)
            self._exact_for = key
        if self._exact and max_code >> self.lvds.word_bits == 0:
            return frames
        # Scrambled, or words too wide for the link (which ``receive`` refuses).
        return self.lvds.receive_block(frames, self.alignment)

    def _alignment_key(self) -> tuple[object, ...]:
        """What ``bit_exact`` depends on (the alignment and the lanes' skews), to keep its
        answer until one of them changes."""
        assert self.lvds is not None
        a = self.alignment
        return (
            tuple(a.taps), tuple(a.slips), tuple(a.shifts), a.latency,
            tuple(self.lvds.skews), self.lvds.dead_lanes,
        )  # fmt: skip

    # -- helpers ------------------------------------------------------------------------------

    def _dark_lanes(self) -> set[int]:
        """Lanes that send nothing: disabled in the ``lvds_lanes`` role's bits, or every lane
        while the ``lvds_clock`` role's clock lane is off (docs/sensors.md, hr400 LVDS_CTRL).
        A map without these roles has every lane on."""
        clock_on, enabled = True, (1 << self.lanes) - 1
        if self.regmap.role("lvds_clock") is not None:
            reg, field = self._role("lvds_clock")
            clock_on = bool(field.extract(self.spi.read(reg.address)))
        if self.regmap.role("lvds_lanes") is not None:
            reg, field = self._role("lvds_lanes")
            enabled = field.extract(self.spi.read(reg.address))
        return {i for i in range(self.lanes) if not (clock_on and enabled >> i & 1)}

    def _role(self, role: str) -> tuple[RegisterSpec, FieldSpec]:
        name = self.regmap.role(role)
        if name is None:
            raise RuntimeError(f"sensor {self.regmap.sensor}'s register map has no {role} role")
        target, field = self.regmap.resolve(name)
        assert isinstance(target, RegisterSpec)
        return target, field if field is not None else target.all_fields()[0]

    def _set_pattern(self, reg: RegisterSpec, field: FieldSpec, base: int, mode: str) -> None:
        if field.enum is None or mode not in field.enum:
            raise RuntimeError(f"{reg.name}.{field.name} has no {mode!r} pattern")
        self.spi.write(reg.address, field.insert(base, field.enum[mode]))


def _without(result: TrainingResult, dark: set[int]) -> TrainingResult:
    """``result`` with the ``dark`` lanes unlocked: no data, no eye, nothing to align."""
    if not dark:
        return result
    lanes = [
        replace(lane, tap=0, eye_width_taps=0, slips=0, shift=0, locked=False, eye="",
                reason="the lane sends no data (disabled, or the clock lane is off)")
        if lane.lane in dark else lane
        for lane in result.lanes
    ]  # fmt: skip
    return TrainingResult(result.alignment, lanes)
