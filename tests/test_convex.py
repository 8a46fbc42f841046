"""The convex planner against independent computations: the exact plant, the decomposition, the
focus's own field, the limits and drifted truths."""

import warnings
from dataclasses import replace

import numpy as np
import pytest

from modalctl.model.propagate import Plant
from modalctl.model.scenes import load_scene
from modalctl.model.shape import parse_params
from modalctl.options import PlanOptions
from modalctl.plan.convex import Program
from modalctl.plan.decompose import decompose
from modalctl.plan.planner import PlanError, plan
from modalctl.plugin.manager import get_shape

FS = 500e3
TF = 0.025


@pytest.fixture(scope="module")
def case():
    """thesis-al-cc on 211 points, the thesis's margin case (sinc 18 mm at 24 mm, 9 modes)."""
    model = load_scene("thesis-al-cc", 211)
    sinc = get_shape("sinc")
    shape = sinc.generate(model.grid, **parse_params(sinc, {"width": "18mm", "center": "24mm"}))
    return model, shape, decompose(model, shape, 9)


def convex(**changes) -> PlanOptions:
    return PlanOptions(**{"planner": "convex", "margin": 0.5, "sample_rate": FS, **changes})


@pytest.fixture(scope="module")
def margin_plan(case):
    return plan(case[2], TF, convex())


def whole_field(model, volts, fs=FS):
    """Every grid point's velocity at every DAC sample (n, N), the plant run independently."""
    return model.shapes.T @ Plant(model, fs).simulate(volts)


def ratio(field, mask, focus):
    return float(np.abs(field[~mask]).max() / np.abs(field[:, focus]).max())


def test_the_plans_field_on_the_plant_is_its_prediction(case, margin_plan):
    """The program's rows (tabulated responses, shifted copies, free decay) times its solution give
    every mode's velocity at any sample as the plant does, to 1e-9; so does its margin ratio."""
    model, shape, dec = case
    volts = margin_plan.voltages()
    velocity = Plant(model, FS).simulate(volts)
    program = Program(model, dec.modes_used, margin_plan.targets, shape.target_mask, TF, convex())
    x = np.linalg.lstsq(np.diag(program.basis.scale), np.r_[
        np.concatenate([np.stack([e.real, e.imag], axis=-1).ravel() for e in margin_plan.drive.envelope]),
        margin_plan.drive.volts.ravel()], rcond=None)[0]  # the columns back from the plan's coefficients
    for n in (100, 6000, program.focus - 37, program.focus, program.focus + 211, program.samples - 1):
        predicted = program.responses[0].velocity(n) @ x
        assert np.max(np.abs(predicted - velocity[:, n])) <= 1e-9 * np.max(np.abs(velocity[:, n]))
    field = model.shapes.T @ velocity
    assert ratio(field, shape.target_mask, program.focus) == pytest.approx(margin_plan.report.whole_model_margin_ratio,
                                                                            abs=1e-9)


def test_the_rows_at_points_are_the_shapes_times_the_modal_velocities(case, monkeypatch):
    """The margin rows, contracted over the modes before they are spread over the columns, are the
    points' shapes times every mode's velocity per column, to round-off: on the nominal model and a
    drifted copy, before, within and after the late bumps' and the hats' support; and so are a
    round's rows made in one call, each at its own sample (in chunks, when they are many)."""
    model, shape, dec = case
    program = Program(model, dec.modes_used, dec.coefficients[dec.modes_used], shape.target_mask, TF,
                      convex(robust_drift=0.01))
    points = program.model.shapes[:, program.outside[[0, 17, 90]]].T  # (3, K)
    samples = (0, 100, 6000, program.focus - 37, program.focus, program.focus + 211, program.samples - 1)
    for responses in (program.responses[0], program.responses[-1]):
        for n in samples:
            want = points @ responses.velocity(n)
            got = responses.rows(n, points)
            assert np.max(np.abs(got - want)) <= 1e-12 * np.max(np.abs(want))
        want = np.vstack([points @ responses.velocity(n) for n in samples])
        for entries in (2**21, 2000):  # 2000: a few rows, and a few lags within the support, at a time
            monkeypatch.setattr("modalctl.plan.convex_basis.ROW_ENTRIES", entries)
            got = responses.rows(np.repeat(samples, 3), np.tile(points, (len(samples), 1)))
            assert np.max(np.abs(got - want)) <= 1e-12 * np.max(np.abs(want))


def test_the_focus_state_is_the_decompositions(case, margin_plan):
    """At T_F every kept mode moves at its coefficient, at its velocity peak (displacement zero),
    and every other mode of the model is still: the field there is the reduced field."""
    model, _, dec = case
    focus = int(round(TF * FS))
    volts = margin_plan.voltages()
    plant = Plant(model, FS)
    velocity = plant.simulate(volts[:, :focus + 1])[:, focus]
    displacement, state_velocity = plant.modal_state()  # at the last sample played: T_F's
    assert np.allclose(state_velocity, velocity, rtol=0, atol=1e-12 * np.abs(velocity).max())
    want = np.zeros(model.n_modes)
    want[dec.modes_used] = dec.coefficients[dec.modes_used]
    scale = np.abs(want).max()
    assert np.max(np.abs(velocity - want)) < 1e-8 * scale
    assert np.max(np.abs(displacement[dec.modes_used] * model.omega[dec.modes_used])) < 1e-8 * scale
    np.testing.assert_allclose(model.shapes.T @ velocity, dec.reconstruction,
                               atol=1e-8 * np.abs(dec.reconstruction).max())


def test_the_margin_holds_on_every_sample_of_the_whole_model(case, margin_plan):
    """The thesis's case: 0.5 on every off-target point and DAC sample of all 21 modes, where the
    kappa = 1 envelopes reach two thirds."""
    model, shape, _ = case
    field = whole_field(model, margin_plan.voltages())
    assert ratio(field, shape.target_mask, int(round(TF * FS))) <= 0.5 + 1e-9
    assert margin_plan.report.program["status"] == "optimal"


@pytest.mark.slow
def test_a_margin_below_the_focus_own_side_lobes_is_refused_with_the_reachable_ratio(case):
    """The reduced sinc's own field off target at T_F is 0.30 of its peak (independently: the
    decomposition's reconstruction): 0.2 cannot be held at T_F itself, whatever the drive. The
    refusal is a proof: those lobes are on every drive that builds the focus."""
    _, shape, dec = case
    lobes = np.abs(dec.reconstruction[~shape.target_mask]).max() / np.abs(dec.reconstruction).max()
    assert lobes > 0.25
    with pytest.raises(PlanError) as refused:
        plan(dec, TF, convex(margin=0.2))
    err = refused.value
    assert err.limit == 0.2 and err.needed >= lobes - 1e-6 and err.needed < 0.5
    assert err.certificate["status"] == "infeasible" and err.certificate["smallest_ratio"] == err.needed
    assert "side lobes" in str(err) and f"{lobes:.3f}" in str(err)


def test_a_margin_out_of_reach_within_a_voltage_limit_is_refused_with_a_ratio_that_is_reachable(case):
    """0.5 needs about 9 V on this case: under 6 V it is refused with the smallest ratio a drive
    within 6 V reaches (bisection on the margin); that ratio is honest, because a plan asked for
    2% above it is found within 6 V and holds it on every sample of the independently simulated
    plant, and the margin it refused lies between 0.5 and it."""
    model, shape, dec = case
    with pytest.raises(PlanError, match="cannot be held within voltage 6 V") as refused:
        plan(dec, TF, convex(voltage_limit=6.0))
    reached = refused.value.needed
    certificate = refused.value.certificate
    assert 0.5 < reached < 0.6 and certificate["status"] == "infeasible"
    assert 0.5 <= certificate["largest_refused"] <= reached
    above = plan(dec, TF, convex(voltage_limit=6.0, margin=reached * 1.02))
    volts = above.voltages()
    assert np.abs(volts).max() <= 6.0 * (1 + 1e-9)
    assert ratio(whole_field(model, volts), shape.target_mask, int(round(TF * FS))) <= reached * 1.02 + 1e-9


def test_voltage_and_slew_limits_hold_on_every_sample(case, margin_plan):
    free = np.abs(margin_plan.voltages())
    free_slew = np.abs(np.diff(margin_plan.voltages(), axis=1)).max() * FS
    volts, slew = 0.8 * free.max(), 0.8 * free_slew
    limited = plan(case[2], TF, convex(voltage_limit=volts, slew_limit=slew))
    v = limited.voltages()
    assert np.abs(v).max() <= volts * (1 + 1e-9)
    assert np.abs(np.diff(v, axis=1)).max() * FS <= slew * (1 + 1e-9)
    assert ratio(whole_field(case[0], v), case[1].target_mask, int(round(TF * FS))) <= 0.5 + 1e-9


@pytest.mark.slow
def test_a_voltage_limit_too_low_for_the_focus_itself_is_refused(case):
    with pytest.raises(PlanError, match="reaches the focus within voltage 0.05 V") as refused:
        plan(case[2], TF, convex(voltage_limit=0.05))
    assert refused.value.certificate["smallest_ratio"] is None


def test_the_robust_margin_holds_across_the_band(case):
    """Planned for +-1%: the margin holds on truths drifted by -1%, 0 and +1% (their own focus
    peaks), where the nominal plan breaks it."""
    model, shape, dec = case
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        robust = plan(dec, TF, convex(robust_drift=0.01))
        nominal = plan(dec, TF, convex())
    focus = int(round(TF * FS))
    worst_nominal = 0.0
    for drift in (-0.01, 0.0, 0.01):
        truth = replace(model, frequencies=model.frequencies * (1 + drift))
        assert ratio(whole_field(truth, robust.voltages()), shape.target_mask, focus) <= 0.5 + 1e-6
        worst_nominal = max(worst_nominal, ratio(whole_field(truth, nominal.voltages()), shape.target_mask, focus))
    assert worst_nominal > 0.5  # robustness was needed


def test_without_a_margin_it_is_the_least_energy_drive_to_the_focus(case, margin_plan):
    """No margin: the same focus state, and less energy than the plan that must also hold it."""
    free = plan(case[2], TF, convex(margin=None))
    energy = [np.sum(p.voltages() ** 2) for p in (free, margin_plan)]
    assert energy[0] < energy[1]
    focus = int(round(TF * FS))
    np.testing.assert_allclose(whole_field(case[0], free.voltages())[:, focus], case[2].reconstruction,
                               atol=1e-8 * np.abs(case[2].reconstruction).max())


@pytest.mark.parametrize("solver", ["clarabel", "osqp"])
def test_other_solvers_reach_the_same_plan(case, margin_plan, solver):
    """The same program with an interior-point and an ADMM solver: the same margin and energy within
    their tolerances (the benchmark compares their speed)."""
    other = plan(case[2], TF, convex(convex=PlanOptions().convex.but(solver=solver)))
    assert other.report.whole_model_margin_ratio <= 0.5 * (1 + 1e-6)
    energy = [np.sum(p.voltages() ** 2) for p in (other, margin_plan)]
    assert energy[0] == pytest.approx(energy[1], rel=2e-2)


def test_a_correction_to_the_thesis_envelopes_holds_the_margin_and_the_focus(case):
    """The other basis: the kappa = 1 envelope plan plus a correction the program finds. Played on
    the exact plant independently: the margin on every sample of the whole model, the focus state
    the decomposition's, and the drive is the envelopes' voltages with the correction added."""
    from modalctl.options import ConvexOptions
    from modalctl.plan.envelope import plan_envelopes

    model, shape, dec = case
    corrected = plan(dec, TF, convex(convex=ConvexOptions(reference="envelope")))
    envelopes = plan_envelopes(dec, TF, PlanOptions(planner="envelope", margin=None, sample_rate=FS))
    np.testing.assert_allclose(corrected.voltages() - corrected.correction, envelopes.voltages(), atol=1e-12)
    assert np.all(corrected.kappa == 1.0) and np.abs(corrected.correction).max() > 1.0  # it did correct
    field = whole_field(model, corrected.voltages())
    focus = int(round(TF * FS))
    assert ratio(field, shape.target_mask, focus) <= 0.5 + 1e-9
    assert ratio(whole_field(model, envelopes.voltages()), shape.target_mask, focus) > 0.6  # what it corrected
    velocity = Plant(model, FS).simulate(corrected.voltages()[:, :focus + 1])[:, focus]
    np.testing.assert_allclose(model.shapes.T @ velocity, dec.reconstruction,
                               atol=1e-8 * np.abs(dec.reconstruction).max())


@pytest.mark.slow
def test_only_the_last_of_the_growing_attempts_seeks_a_certificate(case, monkeypatch):
    """The automatic mode set adds modes while the margin is refused: the attempts followed by
    another refuse at once (their certificate, a bisection of margin programs, took minutes on a
    plate), and the last one's refusal still carries the smallest ratio, proven."""
    from modalctl.plan.planner import plan_shot

    model, shape, _ = case
    calls = []
    original = Program.smallest_ratio
    monkeypatch.setattr(Program, "smallest_ratio", lambda self, *a, **k: calls.append(1) or original(self, *a, **k))
    options = convex(voltage_limit=4.0, modes="auto", added_modes=2)
    with pytest.raises(PlanError, match="cannot be held within voltage 4 V") as refused:
        plan_shot(model, shape, TF, options)
    assert len(calls) == 1 and refused.value.certificate["status"] == "infeasible"
    assert refused.value.needed > 0.5
    calls.clear()
    with pytest.raises(PlanError, match="not certified") as unproven:
        plan_shot(model, shape, TF, convex(voltage_limit=4.0, modes=9).but(
            convex=PlanOptions().convex.but(certify=False)))
    assert not calls and unproven.value.certificate["status"] == "not certified"


@pytest.mark.slow
def test_the_growing_attempts_stop_at_their_time_budget(case, monkeypatch):
    """The attempts adding modes stop once they have taken ``attempts_seconds`` (a voltage limit's
    refusal took 285 s of five attempts on the panel): with none, the first attempt is the last,
    certified; within the budget every attempt runs to its end, uncertified but the last."""
    import modalctl.plan.planner as planner

    model, shape, _ = case
    seen = []
    original = planner.plan
    monkeypatch.setattr(planner, "plan", lambda dec, tf, opts, *a: seen.append(opts.convex) or original(dec, tf, opts, *a))
    options = convex(voltage_limit=4.0, modes="auto", added_modes=2)
    with pytest.raises(PlanError) as refused:
        planner.plan_shot(model, shape, TF, options.but(convex=options.convex.but(attempts_seconds=0.0)))
    assert len(seen) == 1 and seen[0].certify  # the last attempt: certified
    assert refused.value.certificate["status"] == "infeasible" and refused.value.certificate["attempts"] == 1
    assert "stopped growing after 1 attempts, at its 0 s budget" in str(refused.value)
    seen.clear()
    with pytest.raises(PlanError) as refused:
        planner.plan_shot(model, shape, TF, options.but(convex=options.convex.but(attempts_seconds=600.0)))
    assert len(seen) == 3 and not seen[0].certify and not seen[1].certify and seen[-1].certify
    assert "budget" not in str(refused.value)  # the count, not the time, ended it
    for bad in (-1.0, float("nan")):
        with pytest.raises(ValueError, match="attempts_seconds"):
            PlanOptions().convex.but(attempts_seconds=bad)


def test_a_least_energy_program_that_fails_is_a_refusal_not_a_traceback(case, monkeypatch):
    """Without a margin there is nothing to bisect: a failed least-energy program (the tablet
    panel keeping 8 of its 254 modes, every other one held still at T_F: DAQP's overdetermined
    start) is said as a refusal with its status, proven or not."""
    model, shape, _ = case
    dec = decompose(model, shape, modes=(0, 1))
    original = Program.solve
    for status, proven in (("more equalities than the basis's columns can meet", False), ("infeasible", True)):
        monkeypatch.setattr(Program, "solve", lambda self, *a, status=status, **k: replace(original(self, *a, **k),
                                                                                         status=status))
        with pytest.raises(PlanError, match="no drive on this basis reaches the focus") as refused:
            plan(dec, TF, convex(margin=None))
        assert refused.value.certificate["status"] == ("infeasible" if proven else "not certified")
        assert refused.value.certificate["margin"] is None


def test_a_daqp_call_stops_at_its_time():
    """solve_qp's time reaches inside DAQP's call (its time limit): a program DAQP takes tens of
    seconds over (3,000 rows on 2,000 columns) stops within a fraction of one, out of time."""
    import time

    from modalctl.plan.convex_program import _Rows
    from modalctl.plan.qp import OUT_OF_TIME, QP, solve_qp

    rng = np.random.default_rng(0)
    columns = 2000
    rows = _Rows()
    for key, row in enumerate(rng.normal(size=(3000, columns))):
        rows.add(key, row, -1.0, 1.0)
    qp = QP(np.ones(columns), 10 * rng.normal(size=columns), np.zeros((0, columns)), np.zeros(0), rows)
    tic = time.perf_counter()
    _, status, _ = solve_qp("daqp", qp, seconds=0.05)
    assert status == OUT_OF_TIME and time.perf_counter() - tic < 2.0


def test_the_drive_stays_within_the_model_s_band():
    """The hats near T_F are spaced at least the Nyquist interval of the model's highest mode: finer,
    they carried the drive where the model has no mode and cannot say what it excites. plate-glass
    (21 modes up to 11967 Hz), the default closed loop's plan of the 30 mm Gaussian at (20, 10) mm:
    with the 20 us hats a fortieth of the drive's energy lay above 1.5 times the highest mode (2.6e-2;
    a truth with twice the modes measured margin 0.87 there), at the Nyquist interval 2.8e-4. The
    energy is the exact voltages' spectrum over the whole shot, computed here with numpy's FFT."""
    from modalctl.options import LoopOptions, RunOptions
    from modalctl.plan.convex_basis import hat_spacing
    from modalctl.plan.planner import plan_shot

    model = load_scene("plate-glass")
    top = float(model.frequencies.max())
    assert hat_spacing(20e-6, top) == pytest.approx(1 / (2 * top)) and hat_spacing(20e-6, 96.6e3) == 20e-6
    assert hat_spacing(20e-6, 19.9e3) == 20e-6  # within 1.5x of the band (the tablet panel's): kept
    gaussian = get_shape("gaussian")
    target = gaussian.generate(model.grid, **parse_params(gaussian, {"width": "30mm", "center": "20mm,10mm"}))
    options = RunOptions(TF, PlanOptions(), LoopOptions()).planned
    _, made = plan_shot(model, target, TF, options)
    volts = made.voltages()
    energy = np.abs(np.fft.rfft(volts, axis=1)) ** 2
    frequency = np.fft.rfftfreq(volts.shape[1], 1 / made.sample_rate)
    assert energy[:, frequency > 1.5 * top].sum() / energy.sum() < 1e-3
    assert made.report.whole_model_margin_ratio <= options.margin * (1 + 1e-6)


def test_daqp_on_a_working_set_finds_the_whole_program_s_optimum():
    """A round's solve, warm-started from the last round's multipliers, runs DAQP on the rows they hold
    active and the round's new rows, then adds the rows its solution breaks until none does: its
    answer is the whole program's optimum, by the optimality conditions checked on every row
    (feasible, multipliers of the right sign only on rows at their bounds, the gradient balanced),
    with more rows active at the warm start than the 400 up to which it once had a working set."""
    from modalctl.plan.convex_program import _Rows
    from modalctl.plan.qp import QP, solve_qp

    rng = np.random.default_rng(1)
    columns, first, more = 450, 900, 300
    a = rng.normal(size=(first + more, columns))
    equality, linear = np.ones((1, columns)), 40 * rng.normal(size=columns)

    def program(n):
        rows = _Rows()
        for key, row in enumerate(a[:n]):
            rows.add(key, row, -1.0, 1.0)
        return QP(np.ones(columns), linear, equality, np.array([3.0]), rows)

    _, status, duals = solve_qp("daqp", program(first))
    assert status == "optimal" and np.count_nonzero(duals) > 400  # the warm start: hundreds of rows active
    x, status, multipliers = solve_qp("daqp", program(first + more), duals=duals)
    assert status == "optimal" and np.count_nonzero(multipliers[1 + first:]) > 0  # the new rows took part
    value, inequality = a @ x, multipliers[1:]
    assert abs(x.sum() - 3.0) < 1e-8 and np.all(np.abs(value) <= 1.0 + 1e-6)  # every row held, not only the set's
    assert np.all(np.abs(value[inequality > 0] - 1.0) < 1e-6) and np.all(np.abs(value[inequality < 0] + 1.0) < 1e-6)
    gradient = x + linear + equality.T @ multipliers[:1] + a.T @ inequality  # H x + f + A' lambda
    assert np.max(np.abs(gradient)) < 1e-6 * np.max(np.abs(linear))
    cold, _, _ = solve_qp("daqp", program(first + more))  # and every row from the start: the same drive
    assert np.max(np.abs(x - cold)) < 1e-6
