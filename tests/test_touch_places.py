"""Where the touch estimator looks for a touch on a plate's many points: candidate places spread over
the modes' patterns, refined among the points each stands for, and the search skipped only when
no place could win (modalctl.loops.touch_estimator)."""

import numpy as np
import pytest

from modalctl.loops.touch_estimator import CANDIDATES, SEARCH_WORK, TouchEstimator, candidate_places
from modalctl.model.propagate import hold_coefficients


def _plate(nx=80, ny=50, modes=12):
    """A simply supported plate's first modes on an nx x ny grid (4000 points): shapes (k, n)."""
    x, y = np.meshgrid(np.linspace(0, 1, nx), np.linspace(0, 1, ny), indexing="ij")
    orders = sorted(((m, n) for m in range(1, 6) for n in range(1, 6)), key=lambda o: o[0] ** 2 + 1.6 * o[1] ** 2)
    shapes = np.array([np.sin(m * np.pi * x) * np.sin(n * np.pi * y) for m, n in orders[:modes]]) * 20
    return shapes.reshape(modes, -1)


def _estimator(shapes, **kw):
    k = shapes.shape[0]
    return TouchEstimator(np.linspace(400, 4000, k), [0.01] * k, shapes, 20e3, **kw)


def _touched(estimator, shapes, at, damping, periods=300, seed=0):
    """Envelopes (n, k) of every mode damped by ``damping`` N s/m at grid point ``at``, driven by
    a growing carrier envelope, and the drive (n, k)."""
    rng = np.random.default_rng(seed)
    k, period = estimator.a.size, estimator.period
    p = np.log(estimator.a) / period - damping * shapes[:, at] ** 2 / 2
    a, g0, g1 = hold_coefficients(p, period, "foh")
    drive = (rng.standard_normal(k) + 1j * rng.standard_normal(k))[:, None] * np.exp(200 * period * np.arange(periods))
    z = np.zeros((k, periods), complex)
    for n in range(1, periods):
        z[:, n] = a * z[:, n - 1] + estimator.r * (g0 * drive[:, n - 1] + g1 * drive[:, n])
    return z.T, drive.T


def test_candidates_stand_for_the_points_whose_pattern_is_nearest():
    """Each point belongs to the cells of the two candidates whose (unit) patterns are nearest its
    own; the points at a node of every mode (the supported edges) to none."""
    shapes = _plate()
    n = shapes.shape[1]
    pattern = shapes.T ** 2
    size = np.linalg.norm(pattern, axis=1)
    live = np.flatnonzero(size > 0)
    assert np.array_equal(candidate_places(shapes[:, :300])[0], live[live < 300])  # few points: every one
    chosen, cells = candidate_places(shapes, 150)
    assert chosen.size == 150 and np.all(np.diff(chosen) > 0)
    member = np.zeros((n, 150), bool)
    for i, cell in enumerate(cells):
        assert chosen[i] in cell
        member[cell, i] = True
    assert np.all(member[live].sum(axis=1) == 2) and not member[size == 0].any()
    unit = pattern[live] / size[live, None]
    distance = np.linalg.norm(unit[:, None, :] - (pattern[chosen] / size[chosen, None])[None], axis=2)
    two = np.sort(distance, axis=1)[:, 1]  # the second nearest candidate's distance
    assert np.all(distance[member[live]].reshape(-1, 2).max(axis=1) <= two + 1e-12)
    assert candidate_places(shapes)[0].size == min(CANDIDATES, SEARCH_WORK // shapes.shape[0])


@pytest.mark.parametrize("at", [17 * 50 + 23, 41 * 50 + 7, 63 * 50 + 38])  # (x, y) indices inside the edges
def test_a_touch_between_the_candidates_is_found_where_it_is(at):
    """4000 points, 341 candidates: a touch of 0.8 N s/m resting on a point that is not one is read
    within 1% on a point whose pattern is the touch's (a plate's symmetric points share it)."""
    shapes = _plate()
    estimator = _estimator(shapes)
    assert estimator.candidates.size < shapes.shape[1]
    z, u = _touched(estimator, shapes, at, 0.8)
    for n in range(z.shape[0]):
        estimator.update(z[n], u[n])
    e = estimator.estimate
    q = shapes ** 2 / 2
    assert np.allclose(q[:, e.index], q[:, at], rtol=1e-6, atol=1e-9 * q.max())
    assert abs(e.damping / 0.8 - 1) < 0.01 and e.fit > 0.99 and e.sure > 0.75


def test_skipping_the_search_changes_no_estimate():
    """The search is skipped when no pattern could move the place: every period's estimate is
    the one of an estimator that searches every period."""
    shapes = _plate()
    skipping, searching = _estimator(shapes), _estimator(shapes)
    each = searching._each
    searching._each = lambda j: (each(j)[0], np.inf)  # no bound: search every period
    z, u = _touched(skipping, shapes, 41 * 50 + 7, 0.5, seed=3)
    rng = np.random.default_rng(4)
    z = z + 1e-3 * np.abs(z).max() * (rng.standard_normal(z.shape) + 1j * rng.standard_normal(z.shape))
    for n in range(z.shape[0]):
        skipping.update(z[n], u[n])
        searching.update(z[n], u[n])
        assert skipping.estimate == searching.estimate
