"""Property-based checks of the edges (issue 26), with hypothesis: whatever a user types into an
option and whatever a model file holds, ``modalctl`` ends in a documented code; never a traceback,
never a hang, never exit 0 on a non-finite or out-of-range value.

The option ranges are read from the parsers themselves (each numeric option's type carries its
:class:`modalctl.units.Bounds`), so a new option is covered as soon as it is declared, and an option
declared without bounds fails the first test here.
"""

import argparse
import json
import math
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from modalctl.cli import build_parser, main
from modalctl.model.modes import ModalModel, ModelError
from modalctl.model.scenes import load_scene

# an otherwise valid call of each command; OUT is replaced by a fresh folder
BASE = {
    "run": ["run", "--scene", "thesis-al-cc", "--points", "61", "--shape", "sinc", "--focus-time", "25ms",
            "--quiet", "--no-plots", "--out", "OUT"],
    "sweep": ["sweep", "--quiet", "--out", "OUT"],
    "identify": ["identify", "--scene", "thesis-al-cc", "--quiet", "--no-plots", "--out", "OUT/model.npz"],
    "emulate": ["emulate", "--for", "0.01s"],
    "decompose": ["decompose", "--scene", "thesis-al-cc", "--shape", "sinc"],
}
UNBOUNDED_ON_PURPOSE = {"--param", "--vary", "--margin", "--drift-step", "--out", "--points", "--modes", "--plot",
                        "--save-model"}  # own checks


def _options():
    """(command, option, Bounds) of every numeric option of every command."""
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    found = []
    for command, p in sub.choices.items():
        for action in p._actions:
            if action.option_strings and action.type is not None:
                found.append((command, action.option_strings[-1], getattr(action.type, "bounds", None)))
    return found


BOUNDED = [(c, o, b) for c, o, b in _options() if b is not None and c in BASE and not b.point]


def _call(argv, tmp: Path) -> int:
    """The exit code of ``modalctl argv`` (argparse's refusals included)."""
    argv = [a.replace("OUT", str(tmp / "out")) for a in argv]
    try:
        return main(argv)
    except SystemExit as exit_:
        return exit_.code


def test_every_numeric_option_declares_its_range():
    loose = [f"{c} {o}" for c, o, b in _options() if b is None and o not in UNBOUNDED_ON_PURPOSE]
    assert not loose, f"options read without bounds: {loose}"
    assert len(BOUNDED) >= 60  # the table above found the options (run, sweep, identify, emulate, decompose)


def _outside(bounds) -> st.SearchStrategy[str]:
    """Text of values the option must refuse: non-finite, out of its range, not a number, not an int."""
    non_finite = st.sampled_from(["nan", "NaN", "inf", "-inf", "+inf", "1e400", "-1e400", "1e999"])
    garbage = st.text(alphabet="abcxyz%/ ", min_size=0, max_size=6).filter(lambda t: t.strip().lower() != "none")
    ranges = []
    if bounds.low is not None:
        below = st.floats(max_value=bounds.low, allow_nan=False, allow_infinity=False)
        ranges.append(below.filter(lambda v: not (v > bounds.low if bounds.low_open else v >= bounds.low)))
    if math.isfinite(bounds.high):
        ranges.append(st.floats(min_value=bounds.high, allow_nan=False, allow_infinity=False, exclude_min=True))
    numbers = st.one_of(*ranges).map(repr) if ranges else st.nothing()
    not_int = st.sampled_from(["1.5", "2e-1", "0.999"]) if bounds.kind is int else st.nothing()
    return st.one_of(non_finite, garbage, numbers, not_int)


@pytest.mark.parametrize("command, option, bounds", BOUNDED, ids=[f"{c} {o}" for c, o, _ in BOUNDED])
@settings(max_examples=12, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_an_option_out_of_its_range_exits_2_before_any_work(tmp_path, capsys, command, option, bounds, data):
    value = data.draw(_outside(bounds), label=option)
    code = _call([*BASE[command], option, value], tmp_path)
    assert code == 2, f"modalctl {command} {option} {value!r} ended with {code}"
    assert option.lstrip("-") in capsys.readouterr().err.replace("_", "-")


@pytest.mark.parametrize("option, value", [
    ("--points", "100000x100000"), ("--points", "1"), ("--points", "0x5"), ("--points", "3x3x3"),
    ("--modes", "0"), ("--modes", "-3"), ("--modes", "10000"), ("--margin", "nan"), ("--margin", "2"),
    ("--param", "width=1e400mm"), ("--param", "width=nanmm"), ("--drift-step", "1e9%@5ms"),
])
def test_the_options_with_their_own_readers_refuse_out_of_range_too(tmp_path, capsys, option, value):
    assert _call([*BASE["run"], option, value], tmp_path) == 2


# -- in range: a real shot, ending in a documented code, and never exit 0 with a non-finite metric --
SHOT = ["run", "--scene", "thesis-al-cc", "--points", "61", "--shape", "sinc", "--param", "width=18mm",
        "--quiet", "--no-plots", "--json", "--planner", "envelope", "--margin", "none", "--out", "OUT"]


@st.composite
def _shot_options(draw) -> list[str]:
    options = ["--focus-time", f"{draw(st.floats(0.5, 60)):.3g}ms",
               "--sample-rate", draw(st.sampled_from(["100kHz", "500kHz", "1MHz"]))]
    if draw(st.booleans()):
        options += ["--loop", "closed", "--control-rate", draw(st.sampled_from(["1Hz", "1kHz", "3kHz", "20kHz", "500kHz"])),
                    "--authority", f"{draw(st.floats(0, 20)):.3g}", "--watchdog", str(draw(st.integers(1, 50)))]
    if draw(st.booleans()):
        options += ["--kappa", f"{draw(st.floats(1e-3, 1e3)):.3g}"]
    if draw(st.booleans()):
        options += ["--drift", f"{draw(st.floats(-0.49, 0.49)):.3g}", "--snr", f"{draw(st.floats(0, 200)):.3g}"]
    if draw(st.booleans()):
        options += ["--finger", f"{draw(st.floats(0, 100)):.3g}Ns/m"]
    return options


@settings(max_examples=10, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(options=_shot_options())
def test_a_shot_with_options_in_range_ends_in_a_documented_code_and_finite_metrics(tmp_path, capsys, options):
    code = _call([*SHOT, *options], tmp_path)
    out = capsys.readouterr().out
    assert code in (0, 1, 2, 3)
    if code == 0:
        metrics = json.loads(out)
        for key in ("tau", "tau_model", "nrmse", "peak_voltage", "margin_ratio"):
            assert math.isfinite(metrics[key]), (key, metrics[key])
    else:  # a refusal says why, on stdout too (--json)
        assert json.loads(out.splitlines()[-1])["code"] == code


# -- model files --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def model_file(tmp_path_factory) -> Path:
    return load_scene("thesis-al-cc", 61).save(tmp_path_factory.mktemp("model") / "beam.npz")


def _arrays(path: Path) -> dict:
    with np.load(path, allow_pickle=False) as data:
        return {k: data[k] for k in data.files}


def _loaded_or_refused(path: Path) -> None:
    """The property: a model file loads into a usable model, or is refused with a ModelError."""
    try:
        model = ModalModel.load(path)
    except ModelError:
        return
    assert np.all(np.isfinite(model.frequencies)) and np.all(model.frequencies > 0)
    assert np.all(np.isfinite(model.shapes)) and np.all(np.isfinite(model.actuator_gains))


@settings(max_examples=40, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_a_damaged_model_file_loads_or_is_refused_never_a_traceback(model_file, tmp_path, data):
    raw = bytearray(model_file.read_bytes())
    damage = data.draw(st.sampled_from(["truncate", "flip", "empty", "garbage"]))
    if damage == "truncate":
        raw = raw[:data.draw(st.integers(0, len(raw) - 1))]
    elif damage == "flip":
        for at in data.draw(st.lists(st.integers(0, len(raw) - 1), min_size=1, max_size=8)):
            raw[at] ^= data.draw(st.integers(1, 255))
    elif damage == "empty":
        raw = bytearray()
    else:
        raw = bytearray(data.draw(st.binary(max_size=2000)))
    path = tmp_path / "damaged.npz"
    path.write_bytes(bytes(raw))
    _loaded_or_refused(path)


@settings(max_examples=40, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_a_model_file_with_hostile_arrays_loads_or_is_refused(model_file, tmp_path, data):
    arrays = _arrays(model_file)
    name = data.draw(st.sampled_from(sorted(arrays)))
    change = data.draw(st.sampled_from(["drop", "nan", "inf", "negative", "reshape", "dtype", "scale", "extra"]))
    value = arrays[name]
    if change == "drop":
        del arrays[name]
    elif change in ("nan", "inf", "negative") and value.dtype.kind == "f" and value.size:
        value = value.copy()
        value.flat[data.draw(st.integers(0, value.size - 1))] = {"nan": np.nan, "inf": np.inf, "negative": -1.0}[change]
        arrays[name] = value
    elif change == "reshape":
        arrays[name] = np.zeros(data.draw(st.lists(st.integers(0, 5), max_size=3)))
    elif change == "dtype":
        arrays[name] = np.asarray(["text"] * max(1, min(value.size, 3)))
    elif change == "scale" and value.dtype.kind == "f":
        arrays[name] = value * data.draw(st.sampled_from([0.0, 1e-300, 3.0, 1e300]))
    elif change == "extra":
        arrays["surprise"] = np.arange(3)
    path = tmp_path / "hostile.npz"
    np.savez(path, **arrays)
    _loaded_or_refused(path)


def test_a_model_file_that_is_a_zip_of_something_else_is_refused(tmp_path):
    path = tmp_path / "other.npz"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("readme.txt", "not a model")
    with pytest.raises(ModelError):
        ModalModel.load(path)
