"""The command line: JSON output, pictures, exit codes and messages on bad input."""

import json

import pytest

from modalctl.cli import main

BASE = ["decompose", "--scene", "thesis-al-cc", "--shape", "sinc", "--param", "width=18mm", "--param", "center=24mm"]


def run(capsys, *args):
    code = main(list(args))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_decompose_json(capsys):
    code, out, _ = run(capsys, *BASE, "--modes", "9", "--json")
    data = json.loads(out)
    assert code == 0
    assert data["modes_used"] == list(range(1, 10))
    assert {"coefficients", "modes_used", "tau", "nrmse", "error_left"} <= set(data)
    assert 0.98 < data["tau"] <= 1.01  # the thesis's 9-mode model of the 18 mm sinc (DESIGN: about 0.99)


def test_decompose_auto_meets_its_target(capsys):
    code, out, _ = run(capsys, *BASE, "--tau-target", "0.995", "--json")
    data = json.loads(out)
    assert code == 0 and data["tau"] >= 0.995 and data["rule"].startswith("smallest set")


def test_decompose_text_and_plot(capsys, tmp_path):
    png = tmp_path / "d.png"
    code, out, _ = run(capsys, *BASE, "--plot", str(png))
    assert code == 0 and "error left" in out
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_model_file_roundtrip(capsys, tmp_path):
    path = tmp_path / "m.npz"
    run(capsys, *BASE, "--save-model", str(path), "--json")
    code, out, _ = run(capsys, "decompose", "--model", str(path), "--shape", "bump", "--param", "width=25mm",
                       "--modes", "all", "--json")
    assert code == 0 and json.loads(out)["n_modes_used"] == 21


@pytest.mark.parametrize("args, words", [
    (["decompose", "--scene", "nope", "--shape", "sinc", "--param", "width=1mm"], ["thesis-al-cc", "plate-glass"]),
    (["decompose", "--scene", "thesis-al-cc", "--shape", "nope"], ["sinc", "bump", "square"]),
    ([*BASE, "--param", "colour=red"], ["colour", "width", "amplitude"]),
    ([*BASE[:-1], "center=24furlongs"], ["furlongs", "mm"]),
    (["decompose", "--model", "/nonexistent/m.npz", "--shape", "sinc", "--param", "width=1mm"], ["no such file"]),
])
def test_bad_input_exits_2_and_lists_what_exists(capsys, args, words):
    code, _, err = run(capsys, *args)
    assert code == 2
    for word in words:
        assert word in err


def test_unreachable_target_exits_1(capsys):
    code, _, err = run(capsys, "decompose", "--scene", "thesis-al-cc", "--shape", "square", "--param", "width=25mm",
                       "--tau-target", "0.9999")
    assert code == 1 and "no mode set meets" in err


def test_scenes_and_plugins(capsys):
    code, out, _ = run(capsys, "scenes", "--json")
    assert code == 0 and "thesis-al-cc" in json.loads(out)
    code, out, _ = run(capsys, "plugins", "--json")
    assert code == 0 and "sinc" in json.loads(out)["shapes"]


@pytest.mark.parametrize("option, value", [("--nrmse-target", "-1"), ("--tau-target", "1.5"), ("--points", "ten")])
def test_decompose_refuses_targets_and_grids_that_mean_nothing(capsys, option, value):
    with pytest.raises(SystemExit) as exit_:
        main([*BASE, option, value])
    assert exit_.value.code == 2 and option.lstrip("-") in capsys.readouterr().err
