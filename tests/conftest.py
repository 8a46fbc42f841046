import numpy as np
import pytest

from modalctl.structures import Beam


@pytest.fixture
def al_beam():
    """The thesis's aluminium beam geometry with typical aluminium properties."""
    return Beam(0.105, 0.007, 0.001, 69e9, 2700, "clamped-clamped")


@pytest.fixture
def rng():
    return np.random.default_rng(1234)
