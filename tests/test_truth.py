"""A truth richer than the model: scenes continued to more modes, a truth from a model file, and
per-mode gain errors (issue 37's spillover; the benchmark is benchmarks/spillover.py)."""

import json

import numpy as np
import pytest

from modalctl.cli import main
from modalctl.hil.scenario import Perturbation, perturb
from modalctl.model.modes import ModelError
from modalctl.model.scenes import _beam_from_table, continued, load_scene
from modalctl.model.structures import Plate

RUN = ["run", "--scene", "thesis-al-cc", "--shape", "sinc", "--param", "width=18mm", "--param", "center=24mm",
       "--focus-time", "25ms", "--quiet", "--no-plots"]


def test_a_thesis_beam_continued_keeps_its_identified_modes_and_scales_the_analytic_ones_above():
    model = load_scene("thesis-al-cc")
    richer = continued(model, 42)
    assert richer.n_modes == 42 and richer.grid.n == model.grid.n
    np.testing.assert_array_equal(richer.frequencies[:21], model.frequencies)
    np.testing.assert_array_equal(richer.shapes[:21], model.shapes)
    np.testing.assert_array_equal(richer.actuator_gains[:21], model.actuator_gains)
    # above the table: the analytic clamped-clamped frequencies times the two highest identified modes'
    # mean ratio measured / analytic, computed here from the beam's own formula
    beam, _ = _beam_from_table("al_cc_beam")
    analytic = beam.frequencies(42)
    ratio = np.mean(model.frequencies[19:21] / analytic[19:21])
    np.testing.assert_allclose(richer.frequencies[21:], analytic[21:] * ratio, rtol=1e-12)
    assert richer.meta["continued_modes"] == list(range(22, 43)) and richer.meta["estimated_modes"] == [18]


def test_a_scene_on_another_grid_is_continued_on_that_grid():
    """A scene built on a grid of its user's (``--points``) is continued on that grid, not refused
    for being off the scene's default one: the same first modes, on the same points."""
    for name, points in (("thesis-al-cc", 211), ("plate-glass", (51, 36))):
        model = load_scene(name, points)
        richer = continued(model, model.n_modes + 5)
        assert richer.grid.n == model.grid.n and np.array_equal(richer.grid.points, model.grid.points)
        np.testing.assert_allclose(richer.shapes[:model.n_modes], model.shapes, rtol=1e-12, atol=1e-12)


def test_the_free_free_beam_continues_its_symmetric_modes_by_two():
    richer = continued(load_scene("thesis-al-ff"), 12)
    assert list(richer.labels) == [1, 3, 5, 7, 9, 11, 13, 15, 17, 19, 21, 23]


def test_the_plate_continued_is_the_analytic_plate_with_more_modes():
    model = load_scene("plate-glass")
    richer = continued(model, 63)
    np.testing.assert_array_equal(richer.frequencies[:21], model.frequencies)
    plate = Plate(0.100, 0.070, 0.001, 70e9, 2500, 0.22)  # the scene's plate
    np.testing.assert_allclose(richer.frequencies, plate.frequencies(plate.mode_indices(63)), rtol=1e-12)
    assert np.all(np.diff(richer.frequencies) >= 0)


def test_continuing_refuses_fewer_modes_and_models_of_no_known_structure():
    model = load_scene("plate-glass")
    with pytest.raises(ModelError, match="between 21"):
        continued(model, 10)
    anonymous = model.select(np.arange(5))
    anonymous = type(model)(**{**anonymous.__dict__, "meta": {"name": "measured"}})
    with pytest.raises(ModelError, match="neither a scene"):
        continued(anonymous, 10)


def test_gain_errors_move_each_mode_by_the_error_up_or_down_and_leave_the_seeds_spread_alone():
    model = load_scene("thesis-al-cc")
    plain = perturb(model, Perturbation(drift_spread=0.01, seed=3))
    erred = perturb(model, Perturbation(drift_spread=0.01, seed=3, gain_error=0.2))
    np.testing.assert_array_equal(erred.frequencies, plain.frequencies)
    factor = erred.actuator_gains / model.actuator_gains
    per_mode = factor[:, 0]
    np.testing.assert_allclose(factor, per_mode[:, None] * np.ones_like(factor), rtol=1e-12)
    np.testing.assert_allclose(np.abs(per_mode - 1), 0.2, rtol=1e-12)
    assert 0 < np.count_nonzero(per_mode > 1) < model.n_modes  # both signs drawn
    with pytest.raises(ValueError, match="gain_error"):
        Perturbation(gain_error=1.5)


def test_a_run_on_a_truth_from_a_model_file_simulates_its_modes(tmp_path, capsys):
    richer = continued(load_scene("thesis-al-cc"), 42)
    path = tmp_path / "truth.npz"
    richer.save(path)
    assert main([*RUN, "--truth", str(path), "--gain-error", "10%", "--out", str(tmp_path / "run")]) == 0
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["device_info"]["modes_available"] == 42
    assert "42 modes" in metrics["device_info"]["truth"] and "gains +-10%" in metrics["device_info"]["truth"]
    assert np.isfinite(metrics["tau"]) and np.isfinite(metrics["margin_ratio"])


def test_a_run_continues_the_scene_for_its_truth_and_cannot_scan_a_truth_coarser_than_the_model(tmp_path, capsys):
    assert main([*RUN, "--truth-modes", "30", "--out", str(tmp_path / "run")]) == 0
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["device_info"]["modes_available"] == 30
    other = load_scene("thesis-al-cc", 501)  # every other point of the model's: the vibrometer misses half
    other.save(tmp_path / "coarse.npz")
    assert main([*RUN, "--truth", str(tmp_path / "coarse.npz"), "--out", str(tmp_path / "bad")]) == 2  # the file's
    assert "nearest scan point" in capsys.readouterr().err


@pytest.fixture(scope="module")
def margin_case():
    """thesis-al-cc's margin case planned for the default closed loop, and its PI loops' parts (the loops the
    poles of cluster_poles model)."""
    from modalctl.loops.shot import loop_parts
    from modalctl.model.shape import parse_params
    from modalctl.options import LoopOptions, PlanOptions, RunOptions
    from modalctl.plan.planner import plan_shot
    from modalctl.plugin.manager import get_shape

    model = load_scene("thesis-al-cc")
    sinc = get_shape("sinc")
    target = sinc.generate(model.grid, **parse_params(sinc, {"width": "18mm", "center": "24mm"}))
    _, plan = plan_shot(model, target, 25e-3, RunOptions(25e-3, PlanOptions(), LoopOptions()).planned)
    return model, target, plan, loop_parts(plan, LoopOptions(controller="pi"), plan.focus_peak / 100)


def _boundary(parts, truth, i, low=0.5, high=4.0) -> float:
    """The gain scale (bisected to 1%) at which loop ``i``'s channel poles on ``truth`` cross into growth."""
    from modalctl.loops.design import cluster_poles

    grows = lambda g: cluster_poles(parts, [i], truth, g).real.max() > 0  # noqa: E731
    assert not grows(low) and grows(high)
    while high / low > 1.01:
        mid = np.sqrt(low * high)
        low, high = (low, mid) if grows(mid) else (mid, high)
    return high


def test_a_loop_alone_on_its_own_mode_keeps_the_gain_margin_it_was_designed_with(margin_case):
    """A mode's own path only: the discrete loop's boundary is the design's gain margin (6 dB, python-control's
    stability_margins on the continuous loop with a Pade delay), within what the hold and sampling change."""
    model, _, plan, parts = margin_case
    i = 0
    alone = model.select(np.array([plan.modes[i]]))
    boundary = _boundary(parts, alone, i)
    assert parts.design.gain_margin_db[i] >= 6.0 - 1e-6
    designed = 10 ** (parts.design.gain_margin_db[i] / 20)
    assert designed * 0.8 <= boundary <= designed * 1.25


def test_the_loops_poles_find_the_loop_the_hil_board_loses_first_and_about_where(margin_case):
    """On the whole structure the weakest loop is mode 7's (its reading sees mode 9 3.3 times its own mode):
    predicted to grow from a gain scale between the designed gains and 1.8; on the HIL board (every mode, its
    own lock-in at the sample rate, the loops unclamped) the designed gains hold and 1.8 times them diverge,
    in that loop's slot."""
    from modalctl.experiments.focus import Bench, run_focus
    from modalctl.loops.runtime import State
    from modalctl.options import LoopOptions

    model, target, plan, parts = margin_case
    active = np.flatnonzero(np.asarray(parts.authority).max(axis=1) > 0)
    boundaries = {int(i): _boundary(parts, model, int(i), high=8.0) for i in active}
    weakest = min(boundaries, key=boundaries.get)
    assert model.labels[plan.modes[weakest]] == 7 and 1.0 < boundaries[weakest] < 1.8
    unclamped = LoopOptions(authority=1e9, controller="pi")
    held = run_focus(model, plan, target, unclamped, Bench(snr_db=40, gain_scale=1.0))
    lost = run_focus(model, plan, target, unclamped, Bench(snr_db=40, gain_scale=1.8))
    assert held.result.state != State.ERROR
    assert lost.result.state == State.ERROR and f"slot {weakest} " in lost.result.reason


@pytest.mark.slow
def test_a_close_pair_of_loops_holds_less_together_than_either_alone_as_the_hil_board_shows():
    """plate-glass's modes 9 and 10 (5502 and 5943 Hz, each lock-in's corner 442 Hz: each passes the other's
    carrier): alone, each loop's poles hold 1.8 times its gains; together (each reads the other's drive) they
    grow from below 1.25 times. On the HIL board, unclamped, 0.8 times the gains hold and 1.4 times diverge in
    one of the pair's slots."""
    from modalctl.experiments.focus import Bench, run_focus
    from modalctl.loops.design import cluster_poles
    from modalctl.loops.runtime import State
    from modalctl.loops.shot import loop_parts
    from modalctl.model.shape import parse_params
    from modalctl.options import LoopOptions, PlanOptions, RunOptions
    from modalctl.plan.planner import plan_shot
    from modalctl.plugin.manager import get_shape

    model = load_scene("plate-glass")
    gaussian = get_shape("gaussian")
    target = gaussian.generate(model.grid, **parse_params(gaussian, {"width": "30mm", "center": "20mm,10mm"}))
    _, plan = plan_shot(model, target, 25e-3, RunOptions(25e-3, PlanOptions(), LoopOptions()).planned)
    parts = loop_parts(plan, LoopOptions(controller="pi"), plan.focus_peak / 100)
    pair = [int(np.flatnonzero(model.labels[plan.modes] == label)[0]) for label in (9, 10)]
    grows = lambda loops, g: cluster_poles(parts, loops, model, g).real.max() > 0  # noqa: E731
    assert not any(grows([i], 1.6) for i in pair)
    assert grows(pair, 1.25)
    unclamped = LoopOptions(authority=1e9, controller="pi")
    assert run_focus(model, plan, target, unclamped, Bench(snr_db=40, gain_scale=0.8)).result.state != State.ERROR
    lost = run_focus(model, plan, target, unclamped, Bench(snr_db=40, gain_scale=1.4)).result
    assert lost.state == State.ERROR and any(f"slot {i} " in lost.reason for i in pair), lost.reason


def test_a_finger_rests_on_the_targets_peak_when_the_truth_lies_on_another_grid(tmp_path):
    """The target lies on the model's grid: the finger goes where its peak is, not to the truth's point of the
    same index (a 105-point model of the beam, the scene's 1051 points as the truth: +24 mm, not -45 mm)."""
    coarse = load_scene("thesis-al-cc", 105)
    coarse.save(tmp_path / "coarse.npz")
    argv = ["run", "--model", str(tmp_path / "coarse.npz"), "--truth", "thesis-al-cc", "--shape", "sinc", "--param",
            "width=18mm", "--param", "center=24mm", "--focus-time", "25ms", "--finger", "1Ns/m", "--quiet",
            "--no-plots", "--out", str(tmp_path / "run")]
    assert main(argv) == 0
    at = json.loads((tmp_path / "run" / "metrics.json").read_text())["device_info"]["finger_at_m"][0]
    assert abs(at - 0.024) < 1.5e-3, at


def test_a_scene_name_is_the_scene_even_beside_a_file_of_that_name(tmp_path, monkeypatch):
    """``--truth plate-glass`` run from a folder holding a file named ``plate-glass``: the scene (review finding:
    the file was read as a model first)."""
    from modalctl.hil.sim_device import _named_truth
    from modalctl.model.scenes import load_scene

    monkeypatch.chdir(tmp_path)
    (tmp_path / "thesis-al-cc").write_bytes(b"not a model")
    truth = _named_truth("thesis-al-cc")
    assert np.array_equal(truth.frequencies, load_scene("thesis-al-cc").frequencies)
