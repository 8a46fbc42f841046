"""Reduction rules and the error they report."""

import numpy as np
import pytest

from modalctl.model.projection import reconstruct
from modalctl.plan.reduction import ReductionError, fit, smallest_set, twenty_percent_rule


def test_twenty_percent_rule_counts_most_pulses():
    c = np.array([[10, 3, 1, 2.5, 0],
                  [8, 3, 1, 0.5, 0],
                  [9, 1, 3, 0.5, 5]])  # threshold 2.0
    assert twenty_percent_rule(c).tolist() == [0, 1]  # mode 2 passes once, mode 3 once, mode 4 once
    assert twenty_percent_rule(c, quorum=0.3).tolist() == [0, 1, 2, 3, 4]
    assert twenty_percent_rule(c, contiguous=True).tolist() == [0, 1]
    assert twenty_percent_rule(np.array([[1, 0, 0.5]]), contiguous=True).tolist() == [0, 1, 2]


def test_smallest_set_is_minimal_and_meets_target(al_beam, rng):
    model = al_beam.modal_model(21)
    c = np.zeros(21)
    c[[0, 4, 9, 15]] = [1.0, -0.6, 0.3, 0.05]
    field = reconstruct(c, model.shapes) + 1e-4 * rng.normal(size=model.grid.n)
    result = smallest_set(field, model.shapes, model.grid.mass, tau_min=0.95)
    assert result.modes.tolist() == [0, 4, 9]
    assert result.tau[0] >= 0.95
    assert fit(field, model.shapes, model.grid.mass, [0, 4]).tau[0] < 0.95  # one fewer fails
    band = smallest_set(field, model.shapes, model.grid.mass, tau_min=0.95, order="frequency")
    assert band.modes.tolist() == list(range(10))


def test_nrmse_target_and_energy_left(al_beam):
    model = al_beam.modal_model(10)
    c = np.array([1.0, 0.5, 0.2, 0.1, 0, 0, 0, 0, 0, 0])
    field = reconstruct(c, model.shapes)
    result = smallest_set(field, model.shapes, model.grid.mass, nrmse_max=0.15)
    assert result.modes.tolist() == [0, 1, 2]
    # Parseval: the energy left is the dropped coefficient squared over the total
    assert result.energy_left[0] == pytest.approx(0.1**2 / np.sum(c**2), rel=1e-6)


def test_unreachable_target_says_what_all_modes_reach(al_beam):
    model = al_beam.modal_model(3)
    field = np.sign(model.grid.x) * 0.04  # a step: far outside three modes
    with pytest.raises(ReductionError, match="all 3 modes reach worst tau"):
        smallest_set(field, model.shapes, model.grid.mass, tau_min=0.99)
