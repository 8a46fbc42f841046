"""Issue 36's wave, the inputs a probe of the command line found on 2026-11-30 ending in an internal error
(exit 4), a device fault that was the user's file (exit 3) or a NaN with exit 0: each now refused at its edge
with exit 2 naming it, or, a shot whose measured field has no focus, exit 1 with its record kept."""

import json
from dataclasses import replace

import numpy as np
import pytest

from modalctl.cli import main
from modalctl.model.scenes import load_scene

RUN = ["run", "--scene", "thesis-al-cc", "--points", "61", "--shape", "sinc", "--param", "width=18mm",
       "--focus-time", "5ms", "--quiet", "--no-plots"]
DECOMPOSE = ["decompose", "--scene", "thesis-al-cc", "--points", "61", "--modes", "4"]


def call(argv) -> int:
    try:
        return main(argv)
    except SystemExit as exit_:  # argparse's own refusals
        return exit_.code


def saved(tmp_path, name, **changes):
    """thesis-al-cc on 61 points saved with ``changes`` to its arrays (``meta_json`` given as text)."""
    model = load_scene("thesis-al-cc", 61)
    path = model.save(tmp_path / "beam.npz")
    with np.load(path, allow_pickle=False) as data:
        arrays = {key: data[key] for key in data.files}
    arrays.update({key: np.array(value) if key == "meta_json" else value for key, value in changes.items()})
    np.savez(tmp_path / name, **arrays)
    return tmp_path / name


def test_a_model_identify_wrote_runs_on_its_own_truth(tmp_path):
    """An identified model has no sensors; the simulator on it as its truth read none and took the
    largest of no readings (exit 4). Open loop it runs."""
    path = saved(tmp_path, "identified.npz", sensor_gains=np.zeros((21, 0)))
    argv = [*RUN[:1], "--model", str(path), *RUN[5:]]
    assert call([*argv, "--out", str(tmp_path / "run")]) == 0
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert np.isfinite(metrics["tau"]) and metrics["tau"] > 0.9


@pytest.mark.parametrize("shape, said", [
    (["--shape", "sinc", "--param", "width=18mm", "--param", "amplitude=0"], "zero on every grid point"),
    (["--shape", "sinc", "--param", "width=18mm", "--param", "amplitude=1e-300m/s"], "lies outside"),
    (["--shape", "sinc", "--param", "width=18mm", "--param", "amplitude=1e300m/s"], "lies outside"),
    (["--shape", "gaussian", "--param", "width=1nm", "--param", "center=0.1234mm"], "zero on every grid point"),
    (["--shape", "sum", "--param", "parts=sinc(width=18mm)+sinc(width=18mm,amplitude=-0.04)"], "parts that cancel"),
])
def test_a_target_with_nothing_to_focus_is_refused(shape, said, capsys):
    """A target zero everywhere had planned a NaN tau and printed it with exit 0 (decompose), or ended in a
    ZeroDivisionError (run); one of 1e-300 m/s underflowed the modal sums."""
    assert call([*DECOMPOSE, *shape]) == 2
    assert said in capsys.readouterr().err


def test_a_shot_whose_field_has_no_focus_is_not_a_success(tmp_path, capsys, monkeypatch):
    """A measured field zero everywhere (an amplifier passing nothing) had exited 0 with tau_norm NaN and
    the margin ratio infinite: now exit 1, the record written, what is not finite said. The amplifier's
    1e-300 Hz that made it is refused first."""
    assert call([*RUN, "--amplifier-bandwidth", "1e-300Hz", "--out", str(tmp_path / "a")]) == 2
    assert "at least 1 Hz" in capsys.readouterr().err
    monkeypatch.setattr("modalctl.run.tau_norm", lambda *a, **k: float("nan"))
    assert call([*RUN, "--out", str(tmp_path / "b")]) == 1
    assert "tau_norm (nan) is not finite" in capsys.readouterr().err
    written = json.loads((tmp_path / "b" / "metrics.json").read_text(), parse_constant=str)
    assert written["tau_norm"] == "NaN" and written["code"] == 1 and "not finite" in written["error"]
    assert call([*RUN, "--json", "--out", str(tmp_path / "c")]) == 1  # a refusal's JSON: error, code, command
    said = json.loads(capsys.readouterr().out.strip().splitlines()[-1], parse_constant=str)
    assert said["code"] == 1 and said["command"] == "run" and "tau_norm" in said["error"]


def test_the_api_refuses_what_the_command_line_does():
    """The floors and ranges live in the options and the decomposition, not only in argparse's types."""
    from modalctl.errors import InputError
    from modalctl.hil.scenario import Perturbation
    from modalctl.model.shape import ParamError, Shape
    from modalctl.options import PlanOptions
    from modalctl.plan.decompose import decompose

    for bad in ({"voltage_limit": 1e-300}, {"slew_limit": 0.5}, {"kappa": 1e300}, {"kappa": 1e-300}):
        with pytest.raises(InputError):
            PlanOptions(**bad)
    with pytest.raises(InputError, match="rails"):
        Perturbation(voltage_limit=1e-6)
    model = load_scene("thesis-al-cc", 61)
    with pytest.raises(ParamError, match="zero on every grid point"):
        decompose(model, Shape(np.zeros(61), np.ones(61, bool)))


def test_model_files_nested_past_python_s_limit_or_without_actuators_are_refused(tmp_path, capsys):
    deep = saved(tmp_path, "deep.npz", meta_json="[" * 100_000 + "]" * 100_000)
    assert call([*DECOMPOSE[:1], "--model", str(deep), "--shape", "sinc", "--param", "width=18mm"]) == 2
    assert "RecursionError" in capsys.readouterr().err  # a RecursionError had escaped json.loads: exit 4
    model = load_scene("thesis-al-cc", 61)
    bare = replace(model, actuator_gains=np.zeros((21, 0)),
                   meta={k: v for k, v in model.meta.items() if k != "actuators"}).save(tmp_path / "bare.npz")
    assert call([*RUN[:1], "--model", str(bare), *RUN[5:], "--out", str(tmp_path / "r")]) == 2
    assert "no actuators" in capsys.readouterr().err  # planner.controllable's max of no gains: exit 4


@pytest.mark.parametrize("options, said", [
    (["--focus-time", "1e-300s"], "shorter than 10 samples"),
    (["--focus-time", "0.5us"], "shorter than 10 samples"),
    (["--planner", "envelope", "--margin", "none", "--kappa", "1e300"], "kappa must lie in"),
    (["--planner", "envelope", "--margin", "none", "--kappa", "1e-300"], "kappa must lie in"),
])
def test_plans_that_cannot_be_made_are_refused_at_their_options(tmp_path, capsys, options, said):
    """A focus time under a sample and a kappa of 1e300 or 1e-300 had reached the planners (an SVD that did
    not converge, casadi's own assertion: exit 4)."""
    assert call([*RUN, *options, "--out", str(tmp_path / "x")]) == 2
    assert said in capsys.readouterr().err


@pytest.mark.parametrize("argv, said", [
    (["--vary", "snr=40", "--methods", ","], "none given"),
    (["--vary", "snr=40", "--vary", "snr=30"], "given twice"),
    (["--methods", "open", "--vary", "seed=" + ",".join(map(str, range(2000))), "--vary",
      "snr=" + ",".join(map(str, range(1, 11)))], "20000 cases"),
])
def test_sweeps_with_no_method_an_axis_twice_or_too_many_cases_are_refused(tmp_path, capsys, argv, said):
    """An empty list of methods had drawn an empty figure (exit 4); an axis given twice was dropped silently;
    and nothing capped the cases, which were built before any check (2.7 GB for 15,000 x 150)."""
    assert call(["sweep", *argv, "--workers", "1", "--out", str(tmp_path / "s")]) == 2
    assert said in capsys.readouterr().err


def test_a_picture_only_png_is_asked_for(tmp_path, capsys):
    """``--plot out.pdf`` had reached matplotlib's PDF writer with PNG's options (a TypeError, exit 4)."""
    assert call([*DECOMPOSE, "--shape", "sinc", "--param", "width=18mm", "--plot", str(tmp_path / "f.pdf")]) == 2
    assert "pictures are PNG" in capsys.readouterr().err
    assert call([*DECOMPOSE, "--shape", "sinc", "--param", "width=18mm", "--plot", str(tmp_path / "f.png")]) == 0
