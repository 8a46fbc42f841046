"""The catch-up of what a touch took before it was read (modalctl.loops.catch_up): against one mode and its
lock-in simulated here with scipy's matrix exponential, and on a finger landing on the beam."""

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.signal import butter

from modalctl.loops.catch_up import CatchUp
from modalctl.model.touch import velocity_residues

RATE, BAND, FOCUS = 20e3, 400.0, 5e-3
F, ZETA = 900.0, 0.004  # Hz, ratio
R = complex(velocity_residues([F], [ZETA])[0])  # the envelope's rate per unit force (about 1/2)
P = -2 * np.pi * F * ZETA


def _lockin():
    """The 4th-order analog Butterworth of corner BAND in controllable canonical form: (A, B, C)."""
    b, a = butter(4, 2 * np.pi * BAND, analog=True)
    n = a.size - 1
    af = np.zeros((n, n))
    af[0, :] = -a[1:] / a[0]
    af[1:, :-1] = np.eye(n - 1)
    bf = np.zeros(n)
    bf[0] = 1.0
    cf = np.zeros(n)
    cf[-1] = b[-1] / a[0]  # the numerator is a constant: the output is the chain's last state, scaled
    return af, bf, cf


def _period():
    """One control period of the mode ``x' = P x + R u`` read through the lock-in, the force ramped linearly
    over the period (the board's ramp): the exact exponential of the system augmented with the force and
    its slope. Returns the (n + 3)-square map of (x, filter state, u, du/dt)."""
    af, bf, _ = _lockin()
    n = af.shape[0]
    big = np.zeros((n + 3, n + 3), complex)
    big[0, 0], big[0, n + 1] = P, R
    big[1:n + 1, 0], big[1:n + 1, 1:n + 1] = bf, af
    big[n + 1, n + 2] = 1.0
    return expm(big / RATE)


def _closed(deficit: complex, planned: complex = 1.0 + 0j, authority: float = 1.0, lead: int = 1):
    """The plan: the mode decaying freely from ``planned``; the truth: ``deficit`` below it, its lock-in
    settled likewise. Each period the reading's error (reference less reading) goes to CatchUp, whose force
    plays ramped from the period ``lead`` later. Returns the envelope's miss at the focus (plan less truth)
    and the forces sent."""
    af, bf, cf = _lockin()
    n = af.shape[0]
    step = _period()
    settled = -np.linalg.solve(af, bf)  # the filter's state on a held unit envelope (DC gain one)
    periods = int(round(1.2 * FOCUS * RATE))
    plan = np.concatenate([[planned], settled * planned])
    plans, references = [], []
    for _ in range(periods):  # the plan alone: the references the loop is given
        plan = (step @ np.concatenate([plan, [0, 0]]))[:n + 1]
        plans.append(plan[0])
        references.append(complex(cf @ plan[1:]))
    truth = np.concatenate([[planned - deficit], settled * (planned - deficit)])
    catch = CatchUp([F], [ZETA], [BAND], RATE, lead, FOCUS, np.array([references]))
    queue, last, forces, miss = [0j] * lead, 0j, [], None
    for period in range(periods):
        playing = queue.pop(0)
        truth = (step @ np.concatenate([truth, [last, (playing - last) * RATE]]))[:n + 1]
        last = playing
        error = references[period] - complex(cf @ truth[1:])
        force = complex(catch.correction(period, np.array([error]), np.array([authority]))[0])
        queue.append(force)
        forces.append(force)
        if miss is None and (period + 1) / RATE >= FOCUS - 1e-12:
            miss = plans[period] - truth[0]
    return miss, np.array(forces)


@pytest.mark.parametrize("lead", [1, 3])
def test_a_deficit_along_the_plan_is_caught_up_by_the_focus_without_overshoot(lead):
    """10% of the envelope lost at the start (a finger's work before it was read), 5 ms to the focus. Left
    alone it would reach the focus 0.089 (the mode's decay). Caught up, the predicted error falls as the time
    left (the gain 1 / tau) down to TAU_MIN = 2 ms, then as exp(-t / TAU_MIN): a miss of about
    0.1 * 2 / 5 * exp(-1) = 0.015 with a perfect prediction; measured 0.011 (lead 1) and 0.010 (lead 3).
    It never overshoots, whatever the link's latency: without the prediction of what the lock-in does not
    show yet, the same loop passed the plan (misses -0.004 and -0.007)."""
    miss, forces = _closed(0.1 + 0j, lead=lead)
    assert 0 < miss.real < 0.15 * 0.1 and abs(miss.imag) < 1e-12
    pushes = forces * R  # what each force adds to the envelope's rate: along the plan
    assert np.all(pushes.real >= -1e-12) and np.abs(pushes.imag).max() < 1e-12
    assert np.abs(forces).max() > 0  # it acted


def test_the_deficit_is_read_along_the_plans_phase_whatever_that_phase():
    """The plan at 70 degrees: the same deficit along it is caught up as well (the forces along it)."""
    turn = np.exp(1j * np.deg2rad(70))
    miss, forces = _closed(0.1 * turn, planned=turn)
    straight, _ = _closed(0.1 + 0j)
    assert abs(miss - straight * turn) < 1e-9
    assert np.abs(np.angle(forces[np.abs(forces) > 0] * R / turn)).max() < 1e-9


@pytest.mark.parametrize("deficit", [-0.1 + 0j, 0.1j], ids=["surplus", "across"])
def test_a_surplus_or_an_error_across_the_plan_is_left_to_the_loops(deficit):
    """A damper only takes, along the motion: more than planned, or an error at right angles to the plan
    (a leak, a drift), is not caught up: no force at all."""
    _, forces = _closed(deficit)
    assert np.abs(forces).max() < 1e-12


def test_no_force_on_a_loop_without_authority_nor_from_the_focus_on():
    _, forces = _closed(0.1 + 0j, authority=0.0)
    assert np.abs(forces).max() == 0
    late = int(FOCUS * RATE)
    catch = CatchUp([F], [ZETA], [BAND], RATE, 1, FOCUS, np.ones((1, late + 10), complex))
    assert catch.correction(late, np.array([0.1 + 0j]), np.array([1.0]))[0] == 0


def test_a_finger_landing_before_the_focus_is_given_back_with_the_catch_up_not_without(monkeypatch):
    """thesis-al-cc's 25 mm bump, 1 N s/m landing at 20 ms on its peak, 40 dB, one shot: the default closed
    loop gives back at least 93% of what the finger took (measured 95.7%), the same shot without the
    catch-up under 90% (86.1%: the loss before the touch was read)."""
    from modalctl.hil.scenario import Perturbation
    from modalctl.hil.sim_device import SimDevice
    from modalctl.loops import touch
    from modalctl.model.scenes import load_scene
    from modalctl.model.shape import parse_params
    from modalctl.options import LoopOptions, PlanOptions, RunOptions
    from modalctl.plan.planner import plan_shot
    from modalctl.plugin.manager import get_shape
    from modalctl.run import run

    model = load_scene("thesis-al-cc")
    generator = get_shape("bump")
    target = generator.generate(model.grid, **parse_params(generator, {"width": "25mm"}))
    peak = (float(model.grid.points[int(np.argmax(np.abs(target.values)))][0]),)
    options = {closed: RunOptions(25e-3, PlanOptions(), LoopOptions() if closed else None) for closed in (False, True)}
    plans = {closed: plan_shot(model, target, 25e-3, options[closed].planned) for closed in (False, True)}

    def peak_of(closed: bool, finger: float) -> float:
        truth = Perturbation(finger=finger, finger_at=peak if finger else None, finger_lands=20e-3 if finger else None,
                             snr_db=40.0, seed=0)
        shot = run(model, target, SimDevice(model, truth), options[closed], planned=plans[closed])
        return float(np.max(np.abs(shot.focus_field)))

    free, opened = peak_of(False, 0.0), peak_of(False, 1.0)
    given = (peak_of(True, 1.0) - opened) / (free - opened)
    made = touch.TouchControl.__init__

    def without(self, *args, **kwargs):
        made(self, *args, **kwargs)
        self.catch_up = None

    monkeypatch.setattr(touch.TouchControl, "__init__", without)
    alone = (peak_of(True, 1.0) - opened) / (free - opened)
    assert given >= 0.93 and alone < 0.9
