"""The grey-gradient sharpness of docs/physics.md §7 [REN15], normalised per pair and by mean^2."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from camd.analysis.sharpness import grey_gradient_sharpness


def test_hand_values() -> None:
    # [[1, 3], [5, 7]]: pairs along axis 0: (5-1)^2 + (7-3)^2 = 32 over 2 pairs; along axis 1:
    # (3-1)^2 + (7-5)^2 = 8 over 2 pairs; mean 4.
    image = np.array([[1.0, 3.0], [5.0, 7.0]])
    assert grey_gradient_sharpness(image, axis="along") == pytest.approx(16.0 / 16.0)
    assert grey_gradient_sharpness(image, axis="across") == pytest.approx(4.0 / 16.0)
    assert grey_gradient_sharpness(image) == pytest.approx(40.0 / 4.0 / 16.0)
    # black 2: the mean above black is 2, differences unchanged.
    assert grey_gradient_sharpness(image, black_dn=2.0) == pytest.approx(40.0 / 4.0 / 4.0)
    assert grey_gradient_sharpness(np.full((5, 7), 123.0)) == 0.0


def test_checkerboard_is_four_m_squared() -> None:
    # Modulation m alternating in both directions: every difference is 2 m mean.
    m, mean = 0.3, 400.0
    checker = mean * (1.0 + m * (-1.0) ** np.add.outer(np.arange(16), np.arange(16)))
    assert grey_gradient_sharpness(checker) == pytest.approx(4.0 * m * m)
    stripes = mean * (1.0 + m * (-1.0) ** np.arange(16))[:, None] * np.ones((1, 16))
    assert grey_gradient_sharpness(stripes, axis="along") == pytest.approx(4.0 * m * m)
    assert grey_gradient_sharpness(stripes, axis="across") == 0.0


def test_blur_lowers_it_and_an_along_track_smear_only_along() -> None:
    rng = np.random.default_rng(7)
    scene = 100.0 + 50.0 * rng.random((64, 64))
    smeared = (scene + np.roll(scene, 1, axis=0)) / 2.0  # a one-row smear along track
    assert grey_gradient_sharpness(smeared) < grey_gradient_sharpness(scene)
    assert grey_gradient_sharpness(smeared, axis="along") < 0.6 * grey_gradient_sharpness(
        scene, axis="along"
    )
    # Across track the smear averages two independent rows: half the variance of differences.
    assert grey_gradient_sharpness(smeared, axis="across") == pytest.approx(
        0.5 * grey_gradient_sharpness(scene, axis="across"), rel=0.15
    )


@given(
    scale=st.floats(1e-3, 1e6),
    black=st.floats(-100.0, 100.0),
    seed=st.integers(0, 2**32 - 1),
)
def test_independent_of_exposure(scale: float, black: float, seed: int) -> None:
    image = 10.0 + np.random.default_rng(seed).random((6, 5))
    reference = grey_gradient_sharpness(image)
    assert grey_gradient_sharpness(scale * image + black, black_dn=black) == pytest.approx(
        reference, rel=1e-6
    )


def test_refusals() -> None:
    with pytest.raises(ValueError, match="needs a 2-D image"):
        grey_gradient_sharpness(np.ones(5))
    with pytest.raises(ValueError, match="no neighbour pairs along axis='both'"):
        grey_gradient_sharpness(np.ones((1, 5)))
    assert grey_gradient_sharpness(np.ones((1, 5)), axis="across") == 0.0
    with pytest.raises(ValueError, match=r"mean level above black is 0 DN.*check black_dn"):
        grey_gradient_sharpness(np.ones((3, 3)), black_dn=1.0)
    with pytest.raises(ValueError, match="NaN or infinite"):
        grey_gradient_sharpness(np.array([[1.0, np.nan], [1.0, 1.0]]))
    with pytest.raises(ValueError, match="axis must be"):
        grey_gradient_sharpness(np.ones((3, 3)), axis="diagonal")  # type: ignore[arg-type]
