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


def _touched(estimator, shapes, at, damping, periods=300, seed=0, detuning=0.0):
    """Envelopes (n, k) of every mode damped by ``damping`` N s/m at grid point ``at`` (and its resonance
    ``detuning`` (k,) rad/s off its carrier), driven by a growing carrier envelope, and the drive (n, k)."""
    rng = np.random.default_rng(seed)
    k, period = estimator.a.size, estimator.period
    p = np.log(estimator.a) / period - damping * shapes[:, at] ** 2 / 2 + 1j * np.asarray(detuning)
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
    searching._each = lambda: (each()[0], [np.inf] * len(each()[1]))  # no bound: search every period
    z, u = _touched(skipping, shapes, 41 * 50 + 7, 0.5, seed=3)
    rng = np.random.default_rng(4)
    z = z + 1e-3 * np.abs(z).max() * (rng.standard_normal(z.shape) + 1j * rng.standard_normal(z.shape))
    for n in range(z.shape[0]):
        skipping.update(z[n], u[n])
        searching.update(z[n], u[n])
        assert skipping.estimate == searching.estimate


def test_a_lost_reading_starts_a_new_pair():
    """Every seventh reading lost: with a restart after each gap the touch is read as without the
    loss (within 1%); pairing the next reading with the one before the gap reads a damping that is
    not the touch's (the mode's own decay over two periods taken as a touch's over one)."""
    shapes = _plate()
    at = 41 * 50 + 7
    whole, restarted, paired = _estimator(shapes), _estimator(shapes), _estimator(shapes)
    z, u = _touched(whole, shapes, at, 0.8)
    for n in range(z.shape[0]):
        whole.update(z[n], u[n])
        if n % 7 == 3:  # lost
            restarted.restart()
            continue
        restarted.update(z[n], u[n])
        paired.update(z[n], u[n])
    assert abs(restarted.estimate.damping / 0.8 - 1) < 0.01 and abs(whole.estimate.damping / 0.8 - 1) < 0.01
    assert not abs(paired.estimate.damping / 0.8 - 1) < 0.1


@pytest.mark.parametrize("damping", [0.0, 0.8])
def test_each_modes_detuning_is_read_beside_the_touch(damping):
    """Resonances 1% above (half the modes) and 2% below their carriers: each mode's detuning is read with
    its sign, never beyond it (what the estimator is sure of: three standard errors short of its least
    squares), at least 60% of it and 90% on the average, with a touch or without; the touch's damping within 2%,
    as without a detuning (a drift turns the residual at right angles to the touch's); no detuning: none read."""
    shapes = _plate()
    k, at = shapes.shape[0], 41 * 50 + 7
    estimator = _estimator(shapes)
    omega = 2 * np.pi * np.linspace(400, 4000, k)
    truth = omega * np.where(np.arange(k) % 2, 0.01, -0.02)
    rng = np.random.default_rng(5)
    for detuning in (truth, np.zeros(k)):
        estimator.reset()
        z, u = _touched(estimator, shapes, at, damping, periods=400, detuning=detuning)
        z = z + 1e-4 * np.abs(z).max() * (rng.standard_normal(z.shape) + 1j * rng.standard_normal(z.shape))
        for n in range(z.shape[0]):
            estimator.update(z[n], u[n])
        read = estimator.detuning()
        if detuning is truth:
            ratio = read / truth
            assert np.all((ratio > 0.6) & (ratio < 1.02)) and ratio.mean() > 0.9, ratio
        if damping:  # within 2%: the envelope model holds the detuning to first order
            assert abs(estimator.estimate.damping / damping - 1) < 0.02
    assert np.count_nonzero(read) == 0  # the last: no detuning, none sure
