import os

# One BLAS/OpenMP thread per test process, set before numpy loads its OpenBLAS. ``make test`` runs
# one pytest worker per core (pytest-xdist); a worker whose OpenBLAS also starts a thread per core
# oversubscribes the machine, and OpenBLAS's spinning threads then make an SVD 10 to 30 times slower
# (measured on a 2-core machine: tests/test_uff.py + test_mdof.py 70 s -> 21 s). The suite's
# matrices are small: one thread is as fast even alone. A value set outside is kept.
for _threads in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_threads, "1")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from modalctl.model.structures import Beam  # noqa: E402


@pytest.fixture
def al_beam():
    """The thesis's aluminium beam geometry with typical aluminium properties."""
    return Beam(0.105, 0.007, 0.001, 69e9, 2700, "clamped-clamped")


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


@pytest.fixture(scope="session")
def sinc18():
    """thesis-al-cc (211 points), the thesis's sinc 18 mm at 24 mm, and its kappa = 1 focus plan at
    25 ms sampled at 500 kHz: ``(model, shape, plan)``."""
    import warnings

    from modalctl.model.scenes import load_scene
    from modalctl.model.shape import parse_params
    from modalctl.options import THESIS_PLAN
    from modalctl.plan.decompose import decompose
    from modalctl.plan.planner import plan
    from modalctl.plugin.manager import get_shape

    model = load_scene("thesis-al-cc", 211)
    sinc = get_shape("sinc")
    shape = sinc.generate(model.grid, **parse_params(sinc, {"width": "18mm", "center": "24mm"}))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return model, shape, plan(decompose(model, shape, "auto"), 0.025, THESIS_PLAN.but(sample_rate=500e3))


def pytest_collection_modifyitems(items):
    """The tests marked ``slow`` first, the rest in their order. ``make test`` hands tests to its
    workers in this order (pytest-xdist's load scheduling, one at a time round the workers at
    first): the long ones are shared out at the start and the short ones fill the gaps, instead of
    one worker finishing a 30 s test while the other waits at the end."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)  # a stable sort
