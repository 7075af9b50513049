"""Fault injector: the --inject contract and the statistics of the injected faults."""

from __future__ import annotations

import math

import numpy as np
import pytest

from firmware_models.inject import GARBAGE_MAX_BYTES, FaultInjector, InjectSpec, InjectSpecError


def _flipped_bits(a: bytes, b: bytes) -> np.ndarray:
    """Per-bit difference of two equal-length byte strings, as a 0/1 array (MSB first)."""
    diff = np.frombuffer(a, np.uint8) ^ np.frombuffer(b, np.uint8)
    return np.unpackbits(diff)


# -- parsing ---------------------------------------------------------------------------------


def test_parse_all_keys_with_spaces() -> None:
    spec = InjectSpec.parse(" ber=1e-4, drop=0.01 ,garbage=0.001,delay_ms=2 ")
    assert (spec.ber, spec.drop, spec.garbage, spec.delay_ms) == (1e-4, 0.01, 0.001, 2.0)
    assert spec.active
    assert spec.describe() == "ber=0.0001 drop=0.01 garbage=0.001 delay_ms=2"


@pytest.mark.parametrize("text", ["", "   ", ","])
def test_parse_empty_means_no_faults(text: str) -> None:
    spec = InjectSpec.parse(text)
    assert spec == InjectSpec()
    assert not spec.active
    assert spec.describe() == "none"


def test_parse_boundaries_are_inclusive() -> None:
    spec = InjectSpec.parse("ber=0.01,drop=0.5,garbage=0,delay_ms=1000")
    assert (spec.ber, spec.drop, spec.garbage, spec.delay_ms) == (0.01, 0.5, 0.0, 1000.0)


def test_unknown_key_lists_the_known_ones() -> None:
    with pytest.raises(InjectSpecError) as info:
        InjectSpec.parse("ber=1e-4,stage_eror=0.1")
    message = str(info.value)
    assert "'stage_eror'" in message
    assert "known keys: ber, drop, garbage, delay_ms" in message


@pytest.mark.parametrize(
    ("text", "key", "shown_value", "valid"),
    [
        ("ber=0.02", "ber", "0.02", "from 0 to 0.01"),
        ("drop=-0.1", "drop", "-0.1", "from 0 to 0.5"),
        ("garbage=0.6", "garbage", "0.6", "from 0 to 0.5"),
        ("delay_ms=1001", "delay_ms", "1001", "from 0 to 1000"),
        ("ber=lots", "ber", "lots", "from 0 to 0.01"),
        ("drop=nan", "drop", "nan", "from 0 to 0.5"),
    ],
)
def test_bad_value_names_key_value_and_range(
    text: str, key: str, shown_value: str, valid: str
) -> None:
    with pytest.raises(ValueError) as info:  # InjectSpecError is a ValueError
        InjectSpec.parse(text)
    assert isinstance(info.value, InjectSpecError)
    message = str(info.value)
    assert f"{key}={shown_value}" in message
    assert valid in message


@pytest.mark.parametrize("text", ["ber", "=0.1", "ber=1e-4,ber=1e-3"])
def test_malformed_items_are_refused(text: str) -> None:
    with pytest.raises(InjectSpecError, match=r"ber=1e-4,drop=0\.01|given twice"):
        InjectSpec.parse(text)


def test_direct_construction_also_validates() -> None:
    with pytest.raises(ValueError):
        InjectSpec(ber=0.5)
    with pytest.raises(ValueError):
        InjectSpec(bogus=1.0)  # type: ignore[call-arg]


def test_checked_gives_the_parse_messages() -> None:
    with pytest.raises(InjectSpecError, match=r"drop=0\.9 is invalid"):
        InjectSpec.checked(drop=0.9)
    assert InjectSpec.checked(delay_ms=5.0).delay_ms == 5.0


# -- bit errors ------------------------------------------------------------------------------


def test_bit_error_rate_matches_the_spec() -> None:
    ber = 1e-3
    data = np.random.default_rng(99).integers(0, 256, 1_000_000, dtype=np.uint8).tobytes()
    injector = FaultInjector(InjectSpec(ber=ber), seed=7)
    out = injector.corrupt(data)
    assert len(out) == len(data)
    flips = _flipped_bits(data, out)
    n_bits = len(data) * 8
    expected = n_bits * ber
    sigma = math.sqrt(n_bits * ber * (1 - ber))
    assert abs(int(flips.sum()) - expected) < 5 * sigma
    assert injector.bit_errors == int(flips.sum())
    # Every bit position in the byte is hit about equally (a wrong mask would skew this).
    per_position = flips.reshape(-1, 8).sum(axis=0)
    per_expected = expected / 8
    assert np.all(np.abs(per_position - per_expected) < 5 * math.sqrt(per_expected))


def test_bit_errors_spread_over_the_whole_buffer() -> None:
    data = bytes(400_000)
    out = FaultInjector(InjectSpec(ber=1e-3), seed=3).corrupt(data)
    flips = _flipped_bits(data, out).reshape(4, -1).sum(axis=1)  # four equal quarters
    assert flips.min() > 0.8 * flips.mean()


def test_zero_ber_returns_the_input_untouched() -> None:
    injector = FaultInjector(InjectSpec(), seed=1)
    data = b"\xeb\x90\x01\x00\x01\x00\x00"
    assert injector.corrupt(data) is data
    assert injector.corrupt(b"") == b""
    assert injector.bit_errors == 0


def test_set_changes_the_rate_at_runtime() -> None:
    injector = FaultInjector(InjectSpec(), seed=1)
    data = bytes(10_000)
    assert injector.corrupt(data) == data
    injector.set(InjectSpec(ber=0.01))
    assert injector.corrupt(data) != data
    assert injector.bit_errors > 0


# -- drops, garbage, delay -------------------------------------------------------------------


def test_drop_rate_and_direction_counters() -> None:
    p, n = 0.05, 100_000
    injector = FaultInjector(InjectSpec(drop=p), seed=11)
    rx = sum(injector.drop("rx") for _ in range(n))
    tx = sum(injector.drop("tx") for _ in range(n))
    sigma = math.sqrt(n * p * (1 - p))
    assert abs(rx - n * p) < 5 * sigma
    assert abs(tx - n * p) < 5 * sigma
    assert (injector.dropped_rx, injector.dropped_tx) == (rx, tx)


def test_no_drops_at_rate_zero() -> None:
    injector = FaultInjector(InjectSpec(), seed=0)
    assert not any(injector.drop("tx") for _ in range(10_000))


def test_garbage_bursts_rate_and_lengths() -> None:
    p, n = 0.1, 20_000
    injector = FaultInjector(InjectSpec(garbage=p), seed=5)
    bursts = [injector.garbage() for _ in range(n)]
    lengths = [len(b) for b in bursts if b]
    assert abs(len(lengths) - n * p) < 5 * math.sqrt(n * p * (1 - p))
    assert injector.garbage_bursts == len(lengths)
    assert min(lengths) == 1
    assert max(lengths) == GARBAGE_MAX_BYTES


def test_response_delay_in_seconds_and_counted() -> None:
    injector = FaultInjector(InjectSpec(delay_ms=2.5), seed=0)
    assert injector.response_delay_s() == pytest.approx(0.0025)
    assert injector.response_delay_s() == pytest.approx(0.0025)
    assert injector.delayed == 2
    injector.set(InjectSpec())
    assert injector.response_delay_s() == 0.0
    assert injector.delayed == 2


def test_counters_use_the_sim_get_injected_names() -> None:
    injector = FaultInjector(InjectSpec(ber=0.01, drop=0.5), seed=2)
    injector.corrupt(bytes(1000))
    injector.drop("rx")
    counters = injector.counters()
    assert set(counters) == {"bit_errors", "dropped_rx", "dropped_tx", "garbage_bursts", "delayed"}
    assert counters["bit_errors"] == injector.bit_errors > 0


# -- reproducibility -------------------------------------------------------------------------


def _run(seed: int) -> tuple[bytes, list[bool], bytes]:
    injector = FaultInjector(InjectSpec(ber=1e-3, drop=0.2, garbage=0.3), seed=seed)
    corrupted = injector.corrupt(bytes(50_000))
    drops = [injector.drop("rx") for _ in range(200)]
    garbage = b"".join(injector.garbage() for _ in range(200))
    return corrupted, drops, garbage


def test_same_seed_same_faults() -> None:
    assert _run(42) == _run(42)


def test_different_seed_different_faults() -> None:
    assert _run(42) != _run(43)
