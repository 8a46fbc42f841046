"""Issue 39: bad input and modalctl's own bugs end with different codes. What the user gave is wrong:
an InputError (or ModelError, ParamError, UnitError, OutDirError), exit 2. Anything else a command
raises (a plain ValueError of numpy's or of a check of the core's contracts, a TypeError, a KeyError)
is a bug: exit 4, one line on stderr naming the file its traceback is in, never the traceback itself
(docs/errors.md)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from modalctl.cli import main
from modalctl.errors import InputError
from modalctl.model.modes import ModelError
from modalctl.model.shape import ParamError
from modalctl.outdir import OutDirError
from modalctl.units import UnitError

ROOT = Path(__file__).resolve().parents[1]
DECOMPOSE = ["decompose", "--scene", "thesis-al-cc", "--points", "61", "--shape", "sinc", "--param", "width=18mm"]
RUN = ["run", "--scene", "thesis-al-cc", "--points", "61", "--shape", "sinc", "--param", "width=18mm",
       "--focus-time", "25ms", "--quiet", "--no-plots", "--planner", "envelope", "--margin", "none"]
BROADCAST = "operands could not be broadcast together with shapes (61,) (60,)"


def call(argv) -> int:
    try:
        return main(argv)
    except SystemExit as exit_:  # argparse's own refusals
        return exit_.code


def said(err: str) -> tuple[str, Path]:
    """The one line a command that failed said, and the file its traceback is in."""
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert "(a bug in modalctl; the traceback is in " in lines[0]
    return lines[0], Path(lines[0].rsplit("the traceback is in ", 1)[1].rstrip(")"))


@pytest.fixture
def broken_decompose(monkeypatch):
    """The projection fails as numpy fails on arrays of the wrong shapes: a bug, not the input's fault."""
    def broken(*_, **__):
        raise ValueError(BROADCAST)

    monkeypatch.setattr("modalctl.plan.decompose.project", broken)


def test_the_edge_s_errors_are_input_errors_and_the_core_s_value_errors_are_not():
    for error in (ModelError, ParamError, UnitError, OutDirError):
        assert issubclass(error, InputError) and issubclass(error, ValueError)
    from modalctl.io.protocol import ProtocolError
    from modalctl.plan.planner import PlanError
    from modalctl.plan.reduction import ReductionError

    for error in (PlanError, ReductionError, ProtocolError):  # a target missed (exit 1), a board's frame
        assert not issubclass(error, InputError)


def test_the_simulator_s_truth_and_a_log_file_are_checked_as_bad_input(tmp_path):
    """The checks reached from the command line through the HIL's truth and a log file raise InputError
    themselves (a wrapper once took every plain ValueError around the device's opening for bad input)."""
    from modalctl.hil.scenario import Perturbation
    from modalctl.loops.recorder import read_log

    with pytest.raises(InputError, match="need a finger"):
        Perturbation(finger_lands=0.01)
    with pytest.raises(InputError, match="gain_error"):
        Perturbation(gain_error=-0.1)
    (tmp_path / "log.json").write_text('{"version": 99, "fields": []}')
    (tmp_path / "log.bin").write_bytes(b"")
    with pytest.raises(InputError, match="log version 99"):
        read_log(tmp_path / "log.bin")


def test_a_value_error_of_numpy_s_in_a_command_is_an_internal_error_with_its_traceback_on_disk(
        capsys, broken_decompose):
    assert call(DECOMPOSE) == 4
    line, path = said(capsys.readouterr().err)
    assert line.startswith(f"modalctl decompose: internal error: ValueError: {BROADCAST} ")
    try:
        text = path.read_text()
        assert "Traceback (most recent call last)" in text and BROADCAST in text and "in broken" in text
        assert "modalctl decompose: internal error" in text.splitlines()[0]
    finally:
        path.unlink()


def test_a_bug_after_the_run_claimed_its_folder_leaves_its_traceback_there_and_the_next_run_removes_it(
        capsys, monkeypatch, tmp_path):
    out = tmp_path / "out"

    def broken(*_, **__):
        raise TypeError("unsupported operand type(s) for *: 'NoneType' and 'float'")

    with monkeypatch.context() as patched:
        patched.setattr("modalctl.cli.run._write_fields", broken)
        assert call([*RUN, "--json", "--out", str(out)]) == 4
    captured = capsys.readouterr()
    line, path = said(captured.err)
    assert path == out / "internal-error.txt" and "TypeError: unsupported operand" in line
    assert "in broken" in path.read_text()
    assert json.loads(captured.out.splitlines()[-1])["code"] == 4
    assert "internal-error.txt" in json.loads((out / "run.json").read_text())["files"]
    assert call([*RUN, "--out", str(out)]) == 0  # the same run again: the traceback of the one before is gone
    assert not path.exists() and (out / "metrics.json").exists()


def test_bad_input_still_exits_2_saying_what_is_wrong(capsys, tmp_path):
    assert call([*DECOMPOSE, "--modes", "999"]) == 2  # more than the 61-point beam's modes: the core's check
    assert "modes: N must lie in 1..21, got 999" in capsys.readouterr().err
    assert call([*RUN, "--focus-time", "25kg", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "unknown unit 'kg'" in err and "internal error" not in err


def test_a_plugin_command_s_plain_value_error_is_still_bad_input(capsys):
    """docs/plugins.md's contract before InputError: a plugin's command refused its input with ValueError
    (emulate's truth, checked by the simulator's Perturbation)."""
    assert call(["emulate", "--finger-at", "10mm", "--for", "0.01s"]) == 2
    err = capsys.readouterr().err
    assert "--finger-at places a finger" in err and "internal error" not in err


def test_an_option_s_type_that_breaks_is_an_internal_error_too(capsys, monkeypatch):
    def broken(text):
        raise KeyError(text)

    monkeypatch.setattr("modalctl.cli.common.modes", broken)
    assert call([*DECOMPOSE, "--modes", "3"]) == 4
    line, path = said(capsys.readouterr().err)
    assert line.startswith("modalctl decompose: internal error: KeyError: '3'")
    path.unlink()


def test_the_process_exits_4_with_one_line_and_no_traceback(tmp_path):
    """The shell's view: the exit status and stderr of ``modalctl`` itself."""
    script = ("import sys, modalctl.plan.decompose as d\n"
              "def broken(*_, **__): raise ValueError('shapes (3,) (4,) not aligned')\n"
              "d.project = broken\n"
              "from modalctl.cli import main\n"
              f"sys.exit(main({DECOMPOSE!r}))\n")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=tmp_path,
                          env={**os.environ, "PYTHONPATH": str(ROOT), "TMPDIR": str(tmp_path)}, timeout=300)
    assert done.returncode == 4, done.stderr
    line, path = said(done.stderr)
    assert path.parent == tmp_path and path.name.startswith("modalctl-decompose-internal-error-")
    assert "shapes (3,) (4,) not aligned" in path.read_text()
