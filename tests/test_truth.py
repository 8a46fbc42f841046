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


def test_a_run_continues_the_scene_for_its_truth_and_refuses_a_truth_on_another_grid(tmp_path, capsys):
    assert main([*RUN, "--truth-modes", "30", "--out", str(tmp_path / "run")]) == 0
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["device_info"]["modes_available"] == 30
    other = load_scene("thesis-al-cc", 501)
    other.save(tmp_path / "coarse.npz")
    assert main([*RUN, "--truth", str(tmp_path / "coarse.npz"), "--out", str(tmp_path / "bad")]) == 2
    assert "grid points" in capsys.readouterr().err
