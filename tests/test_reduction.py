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


def test_a_target_of_the_parity_no_mode_has_is_said_so():
    """Issue 26: thesis-al-ff (symmetric modes only) under an off-centre pulse was told 'finer than
    the model's modes can draw; widen it', and widening made it worse. The message now names the
    missing parity and its share, which is checked here by mirroring the target on x -> -x."""
    import re

    from modalctl.model.scenes import load_scene
    from modalctl.model.shape import parse_params
    from modalctl.plugin.manager import get_shape

    model = load_scene("thesis-al-ff")
    sinc = get_shape("sinc")
    target = sinc.generate(model.grid, **parse_params(sinc, {"width": "18mm", "center": "20mm"})).values
    with pytest.raises(ReductionError, match="symmetric about the middle") as refused:
        smallest_set(target, model.shapes, model.grid.mass, tau_min=0.98)
    x = model.grid.points[:, 0]
    mirrored = np.interp(-x, x, target)  # independent of the grid's order
    odd = (target - mirrored) / 2
    share = np.sum(model.grid.mass * odd**2) / np.sum(model.grid.mass * target**2)
    said = float(re.search(r"(\d+)% of the target's energy is antisymmetric", str(refused.value)).group(1))
    assert said == pytest.approx(100 * share, abs=1)
