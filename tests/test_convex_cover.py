"""The convex planner's off-target cover (:class:`modalctl.plan.convex_cover.Cover`) against the
whole grid: its boxes' bounds hold every point's field at every sample, on random drives of the
program's basis on a plate and a beam, and the ratio a plan on a plate reports is the one its
field has on every point of the grid, the plant run independently."""

from dataclasses import replace

import numpy as np
import pytest

from modalctl.model.propagate import Plant
from modalctl.model.scenes import load_scene
from modalctl.model.shape import parse_params
from modalctl.options import PlanOptions
from modalctl.plan.convex import Program
from modalctl.plan.convex_cover import COMPONENTS, LEAF, SPLITS, Cover
from modalctl.plan.decompose import decompose
from modalctl.plan.planner import plan
from modalctl.plugin.manager import get_shape

FS = 500e3
TF = 0.025
BLOCK = 2048  # samples of the whole grid's field at once in these checks


def convex(**changes) -> PlanOptions:
    return PlanOptions(**{"planner": "convex", "margin": 0.5, "sample_rate": FS, **changes})


def target(model, name, **params):
    generator = get_shape(name)
    return generator.generate(model.grid, **parse_params(generator, params))


@pytest.fixture(scope="module")
def plate():
    """plate-glass (7,171 points, 21 modes), a 30 mm Gaussian at (20, 10) mm on the 17 modes the
    automatic set takes (tau 0.98)."""
    model = load_scene("plate-glass")
    shape = target(model, "gaussian", width="30mm", center="20mm,10mm")
    return model, shape, decompose(model, shape, (0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 12, 13, 15, 16, 19, 20))


def random_drives(model, shape, dec, count, seed):
    """Every mode's velocity (K, N) on ``count`` drives of random columns of the program's basis."""
    modes = np.asarray(dec.modes_used, int)
    program = Program(model, modes, dec.coefficients[modes], shape.target_mask, TF, convex())
    rng = np.random.default_rng(seed)
    return program, [program.play(rng.standard_normal(program.basis.size))[1][0] for _ in range(count)]


def whole_grid_top(model, outside, velocity):
    """The largest off-target |w| at every sample, on every point (the plain product, by blocks)."""
    shapes = model.shapes[:, outside]
    return np.concatenate([np.abs(shapes.T @ velocity[:, n:n + BLOCK]).max(axis=0)
                           for n in range(0, velocity.shape[1], BLOCK)])


def boxes(box):
    yield box
    for child in box.children:
        yield from boxes(child)


def check_every_box(cover, velocity):
    """Each box's bound on each child's points >= the field on every one of those points: in double
    precision, and as the search computes it, in single precision plus the cover's allowance for it."""
    state, k = cover._state(velocity), velocity.shape[0]
    allowance = cover.slack * (cover.reach @ np.abs(velocity))
    for box in boxes(cover.root):
        if not box.children:
            continue
        bounds = box.bounds(velocity.T, np.abs(velocity.T))  # (samples, children)
        single = box.bounds(state[:, :k], state[:, k:])
        assert single.dtype == np.float32
        single = single + allowance[:, None]
        for child, bound, searched in zip(box.children, bounds.T, single.T):
            field = np.abs(cover.values[child.start:child.stop] @ velocity).max(axis=0)
            assert np.all(bound >= field * (1 - 1e-12)), "a box's bound below its points' field"
            assert np.all(searched >= field), "a box's single-precision bound below its points' field"


def test_where_a_bound_is_tight_single_precision_falls_below_the_field_and_the_allowance_holds_it():
    """A mode affine along a line is fitted exactly (no residual): each box's bound is its points' largest
    |w|, attained at its ends. In single precision it falls below that at some samples; with the cover's
    allowance for round-off it never does."""

    x = np.linspace(0.0, 1.0, 301)
    shapes = np.vstack([1.0 + 0.37 * x, np.zeros_like(x)])  # a second mode no point moves
    cover = Cover(shapes, x)
    velocity = np.random.default_rng(17).standard_normal((2, 4000))
    state = cover._state(velocity)
    allowance = cover.slack * (cover.reach @ np.abs(velocity))
    below = 0
    for box in (b for b in boxes(cover.root) if b.children):
        single = box.bounds(state[:, :2], state[:, 2:])
        for child, searched, allowed in zip(box.children, single.T, (single + allowance[:, None]).T):
            field = np.abs(cover.values[child.start:child.stop] @ velocity).max(axis=0)
            below += np.count_nonzero(searched < field)
            assert np.all(allowed >= field)
    assert below > 0  # the allowance is needed


def test_the_single_precision_search_allows_for_its_round_off_whatever_the_modes_sizes():
    """A drive whose modes differ by ten decades in size (one mode carries the field, the others' bounds
    are all round-off): the boxes' single-precision bounds plus the allowance still hold every point."""
    model = load_scene("thesis-al-cc")
    shape = target(model, "sinc", width="18mm", center="24mm")
    dec = decompose(model, shape, 9)
    program, (velocity,) = random_drives(model, shape, dec, 1, seed=13)
    velocity = velocity[:, ::7] * np.logspace(0, -10, velocity.shape[0])[:, None]
    check_every_box(program.cover, velocity)


@pytest.mark.slow
def test_on_random_drives_of_a_plate_the_bound_holds_every_grid_point_at_every_sample(plate):
    """Random columns of the basis drive all 21 modes of the plate: at every sample the cover's
    search (bounds where they suffice, the field below them) is the whole grid's largest |w|
    wherever that exceeds the floor and at least it everywhere; every box's bound holds each of
    its points; its largest value is the whole grid's, exactly."""
    model, shape, dec = plate
    program, drives = random_drives(model, shape, dec, 2, seed=7)
    cover = program.cover
    assert cover.size == program.outside.size and np.array_equal(np.sort(cover.order), np.arange(cover.size))
    for velocity in drives:
        true = whole_grid_top(model, program.outside, velocity)
        for share in (0.0, 0.3, 0.6, 0.9):
            floor = share * true.max()
            top = cover.top(velocity, floor)
            assert np.all(top >= true * (1 - 1e-12))
            above = true > floor
            np.testing.assert_allclose(top[above], true[above], rtol=1e-12, atol=0)
            assert np.all(top[~above] <= floor)
        assert cover.largest(velocity) == pytest.approx(true.max(), rel=1e-12)
        check_every_box(cover, velocity[:, ::37])


@pytest.mark.slow
def test_on_a_random_drive_of_the_fe_panel_the_bound_holds_every_grid_point_at_every_sample():
    """The same on panel-rounded (finite elements: 8,591 points on a rounded outline with a slot,
    22 modes), the 30 mm bump the issue plans, on the 17 modes it keeps."""
    model = load_scene("panel-rounded")
    shape = target(model, "bump", width="30mm", center="-20mm,5mm")
    dec = decompose(model, shape, "auto", tau_min=0.95)
    program, (velocity,) = random_drives(model, shape, dec, 1, seed=5)
    true = whole_grid_top(model, program.outside, velocity)
    for share in (0.0, 0.5, 0.9):
        top = program.cover.top(velocity, share * true.max())
        assert np.all(top >= true * (1 - 1e-12))
        above = true > share * true.max()
        np.testing.assert_allclose(top[above], true[above], rtol=1e-12, atol=0)
    assert program.cover.largest(velocity) == pytest.approx(true.max(), rel=1e-12)
    check_every_box(program.cover, velocity[:, ::29])


def test_on_random_drives_of_a_beam_the_bound_holds_every_grid_point_at_every_sample():
    """The same on a beam (one coordinate): thesis-al-cc on 1,051 points, 21 modes."""
    model = load_scene("thesis-al-cc")
    shape = target(model, "sinc", width="18mm", center="24mm")
    dec = decompose(model, shape, 9)
    program, drives = random_drives(model, shape, dec, 2, seed=3)
    for velocity in drives:
        true = whole_grid_top(model, program.outside, velocity)
        top = program.cover.top(velocity, 0.5 * true.max())
        assert np.all(top >= true * (1 - 1e-12))
        np.testing.assert_allclose(top[true > 0.5 * true.max()], true[true > 0.5 * true.max()], rtol=1e-12)
        assert program.cover.largest(velocity) == pytest.approx(true.max(), rel=1e-12)
        check_every_box(program.cover, velocity[:, ::11])


@pytest.mark.parametrize("leaf, splits, components", [(8, 1, 0), (16, 3, 2), (LEAF, SPLITS, COMPONENTS), (64, 6, 0),
                                                      (32, 4, 40)])
def test_the_boxes_size_and_fan_out_change_the_work_not_the_answer(leaf, splits, components):
    """How small the boxes get, how many children each has and how many of their residuals' components
    they keep apart (``benchmarks/margin_check.py`` picks them for speed; 40, more than the beam's
    modes or a leaf's points: rows of zeros): on the beam's random drives the search is the whole
    grid's largest |w| wherever that exceeds the floor, at most the floor elsewhere, and every box's
    bound holds its points."""
    model = load_scene("thesis-al-cc")
    shape = target(model, "sinc", width="18mm", center="24mm")
    dec = decompose(model, shape, 9)
    program, (velocity,) = random_drives(model, shape, dec, 1, seed=17)
    cover = Cover(model.shapes[:, program.outside], model.grid.points[program.outside], leaf=leaf, splits=splits,
                  components=components)
    true = whole_grid_top(model, program.outside, velocity)
    floor = 0.4 * true.max()
    top = cover.top(velocity, floor)
    above = true > floor
    np.testing.assert_allclose(top[above], true[above], rtol=1e-12, atol=0)
    assert np.all(top[~above] <= floor) and np.all(top >= true * (1 - 1e-12))
    assert cover.largest(velocity) == pytest.approx(true.max(), rel=1e-12)
    check_every_box(cover, velocity[:, ::13])


def test_the_field_it_gives_is_exact_wherever_it_may_exceed_the_floor(plate):
    """:meth:`Cover.field` (the rows' lobes are searched on it): the whole grid's field at every
    point whose |w| exceeds the floor, zero only where it does not."""
    model, shape, dec = plate
    program, (velocity,) = random_drives(model, shape, dec, 1, seed=11)
    columns = velocity[:, program.focus - 40:program.focus + 40]
    full = model.shapes[:, program.outside].T @ columns
    floor = 0.5 * np.abs(full).max()
    field = program.cover.field(columns, floor)
    np.testing.assert_allclose(field[np.abs(full) > floor], full[np.abs(full) > floor], rtol=1e-12)
    given = field != 0
    np.testing.assert_allclose(field[given], full[given], rtol=1e-12)
    assert np.all(np.abs(full[field == 0]) <= floor)


@pytest.mark.slow
def test_a_plate_plan_holds_the_margin_on_every_grid_point(plate):
    """Planned under 0.5 on the plate, played on the plant independently: the ratio it reports is
    the whole grid's at every sample (to round-off), and within the margin; and the same on the
    drifted copies of a robust plan, each over its own focus peak."""
    model, shape, dec = plate
    focus = int(round(TF * FS))
    for options, drifts in ((convex(), ()), (convex(robust_drift=0.01), (-0.01, -0.005, 0.005, 0.01))):
        the_plan = plan(dec, TF, options)
        reported = [the_plan.report.whole_model_margin_ratio, *the_plan.report.details.get("robust_margin_ratios", [])]
        assert len(reported) == 1 + len(drifts)
        for drift, ratio in zip((0.0, *drifts), reported):
            truth = replace(model, frequencies=model.frequencies * (1 + drift))
            velocity = Plant(truth, FS).simulate(the_plan.voltages())
            off = whole_grid_top(model, np.flatnonzero(~shape.target_mask), velocity).max()
            peak = np.abs(model.shapes.T @ velocity[:, focus]).max()
            assert off / peak == pytest.approx(ratio, rel=1e-9)
            assert off / peak <= 0.5 * (1 + 1e-4)


def test_a_lobe_on_a_plate_is_one_row_not_one_per_grid_line(plate):
    """Two bumps of |w| off target: two crests (the rows' places), each the largest point of its
    bump over its neighbours in the plane, where a crest along each grid line gave one per line."""
    model, shape, dec = plate
    modes = np.asarray(dec.modes_used, int)
    program = Program(model, modes, dec.coefficients[modes], shape.target_mask, TF, convex())
    points = model.grid.points[program.outside]
    centres = points[[100, points.shape[0] - 300]]
    size = sum(np.exp(-np.sum((points - c) ** 2, axis=1) / (2 * 0.006 ** 2)) for c in centres)
    crests = program.cover.lobes(size, 0.5)
    np.testing.assert_allclose(np.sort(points[crests], axis=0), np.sort(centres, axis=0), atol=1e-12)


@pytest.fixture(scope="module")
def beam_case():
    """thesis-al-cc on 211 points, the thesis's margin case (sinc 18 mm at 24 mm, 9 modes)."""
    model = load_scene("thesis-al-cc", 211)
    shape = target(model, "sinc", width="18mm", center="24mm")
    return model, shape, decompose(model, shape, 9)


def test_a_certificate_stopped_by_its_budget_says_what_it_proved(beam_case, monkeypatch):
    """0.5 within 6 V is refused (test_convex.py: the smallest ratio 0.51-0.6). With a budget of
    two and a half programs (a clock that counts programs), the bisection stops after the
    least-energy drive and two margin programs; the refusal says so, and what it says it proved
    holds: a plan asked for the ratio it says a drive reaches is found within 6 V and holds it on
    every sample of the plant run independently, and the margin it says it refused is below it."""
    import types

    import modalctl.plan.convex_program as program_module
    from modalctl.options import ConvexOptions
    from modalctl.plan.planner import PlanError

    model, shape, dec = beam_case
    clock = {"now": 0.0}
    monkeypatch.setattr(program_module, "_time", types.SimpleNamespace(perf_counter=lambda: clock["now"]))
    original = Program.solve

    def one_second_each(self, *args, **kwargs):
        found = original(self, *args, **kwargs)
        clock["now"] += 1.0
        return found

    monkeypatch.setattr(Program, "solve", one_second_each)
    options = convex(voltage_limit=6.0, convex=ConvexOptions(certify_seconds=2.5))
    with pytest.raises(PlanError, match="budget") as refused:
        plan(dec, TF, options)
    certificate = refused.value.certificate
    assert certificate["bisection"]["complete"] is False and certificate["bisection"]["programs"] == 3
    assert certificate["status"] == "infeasible"  # the margin program's own failure was the solver's proof
    reached = refused.value.needed
    assert 0.5 <= certificate["largest_refused"] < reached and reached == certificate["smallest_ratio"]
    assert f"{reached:.3f}" in str(refused.value) and "lies between" in str(refused.value)
    monkeypatch.undo()
    held = plan(dec, TF, convex(voltage_limit=6.0, margin=reached * (1 + 1e-4)))
    volts = held.voltages()
    assert np.abs(volts).max() <= 6.0 * (1 + 1e-9)
    field = model.shapes.T @ Plant(model, FS).simulate(volts)
    focus = int(round(TF * FS))
    assert np.abs(field[~shape.target_mask]).max() / np.abs(field[:, focus]).max() <= reached * (1 + 1e-4) + 1e-9


def test_a_certificate_with_no_time_gives_the_least_energy_drives_ratio(beam_case):
    """A budget of zero: the least-energy drive within 6 V alone (its program starts from the rows
    the refused one found), no bisection; the refusal gives its ratio as reached, the margin asked
    as the largest refused, and says the margin program's failure was the solver's proof."""
    from modalctl.options import ConvexOptions
    from modalctl.plan.planner import PlanError

    _, _, dec = beam_case
    with pytest.raises(PlanError, match="budget") as refused:
        plan(dec, TF, convex(voltage_limit=6.0, convex=ConvexOptions(certify_seconds=0.0)))
    certificate = refused.value.certificate
    bisection = certificate["bisection"]
    assert bisection["complete"] is False and bisection["programs"] == 1 and bisection["free"] == "optimal"
    assert certificate["largest_refused"] == 0.5 and refused.value.needed > 0.5
    assert certificate["status"] == "infeasible" and "solver's proof" in str(refused.value)


@pytest.mark.parametrize("certify_seconds", [0.0, None])
def test_a_margin_program_stopped_by_its_budget_says_so_and_proves_nothing(beam_case, certify_seconds):
    """The margin case's program needs more than one round (its first drive reaches 0.66 of the focus
    peak). With no time (``program_seconds`` 0) its first round ends and it stops there: the refusal
    says so first, and since the program proved nothing the certificate is "not certified" whatever
    its bisection did. Without a budget on the bisection, the bisection finds the drive that holds
    the margin, and the refusal says a longer budget finds the plan; the plan found with the default
    budget holds it on every sample of the plant run independently."""
    from modalctl.options import ConvexOptions
    from modalctl.plan.planner import PlanError

    model, shape, dec = beam_case
    budget = ConvexOptions(program_seconds=0.0, certify_seconds=certify_seconds)
    with pytest.raises(PlanError, match=r"stopped at its 0 s budget \(--plan-time, ConvexOptions.program_seconds\) "
                                        r"after 1 rounds") as refused:
        plan(dec, TF, convex(convex=budget))
    certificate = refused.value.certificate
    assert certificate["status"] == "not certified" and certificate["program_seconds"] == 0.0
    assert certificate["margin_program"] == "out of time"
    if certify_seconds is None:
        assert refused.value.needed <= 0.5 * (1 + 1e-4)
        assert "a longer --plan-time (ConvexOptions.program_seconds) finds the plan" in str(refused.value)
    else:
        assert refused.value.needed > 0.5 and "unproven" in str(refused.value)
    held = plan(dec, TF, convex())
    field = model.shapes.T @ Plant(model, FS).simulate(held.voltages())
    focus = int(round(TF * FS))
    assert np.abs(field[~shape.target_mask]).max() / np.abs(field[:, focus]).max() <= 0.5 * (1 + 1e-4) + 1e-9


@pytest.mark.parametrize("name", ["certify_seconds", "program_seconds", "attempts_seconds"])
def test_a_time_budget_is_none_or_zero_or_more_seconds(name):
    """Each budget: None (no limit) and 0 (stop after the first round or program) are budgets; a
    negative or NaN number is refused naming the option, never taken for no limit."""
    from modalctl.errors import InputError
    from modalctl.options import ConvexOptions

    assert getattr(ConvexOptions(**{name: None}), name) is None and getattr(ConvexOptions(**{name: 0.0}), name) == 0
    for bad in (-1.0, float("nan")):
        with pytest.raises(InputError, match=name):
            ConvexOptions(**{name: bad})


@pytest.mark.parametrize("m, k", [(62, 255), (1000, 53), (5, 9)])
def test_the_boxes_residual_components_are_about_the_leading_singular_ones(m, k):
    """The components a box bounds apart (a seeded randomized range finder) leave about what the
    truncated SVD leaves (numpy's, computed independently), on a matrix of a few strong directions and
    noise; and no more than its rank."""
    from modalctl.plan.convex_cover import _leading

    rng = np.random.default_rng(5)
    rank = min(3, m, k)
    left = rng.standard_normal((m, rank)) @ (10 * rng.standard_normal((rank, k))) + 0.01 * rng.standard_normal((m, k))
    a, b = _leading(left, 4)
    assert a.shape == (m, min(4, m, k)) and b.shape == (k, min(4, m, k))
    s = np.linalg.svd(left, compute_uv=False)
    best = np.sqrt(np.sum(s[a.shape[1]:] ** 2))  # what the truncated SVD of that rank leaves (Frobenius)
    assert np.linalg.norm(left - a @ b.T) <= 1.05 * best
