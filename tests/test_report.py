"""Pictures: importing them leaves matplotlib's backend alone, and a one-panel picture composes."""

import json
import os
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest
from matplotlib.figure import Figure

from modalctl import report

CHECK = ("import matplotlib; before = matplotlib.get_backend(); import modalctl.report; "
         "print(before, matplotlib.get_backend())")


def test_importing_report_leaves_the_backend_as_it_was():
    """A notebook's backend (here svg) survives ``import modalctl.report`` (issue 35: it switched to Agg)."""
    env = {**os.environ, "MPLBACKEND": "svg"}
    run = subprocess.run([sys.executable, "-c", CHECK], capture_output=True, text=True, env=env, check=True)
    assert run.stdout.split() == ["svg", "svg"], run.stdout + run.stderr


def fake_shot():
    """What the one-panel pictures read of a shot: 8 actuators, 3 of them driven, for 30 ms at 100 kHz."""
    fs = 100e3
    times = np.arange(3000) / fs
    voltages = np.zeros((8, times.size))
    voltages[:3] = np.sin(2 * np.pi * np.array([[1e3], [3e3], [5e3]]) * times) * np.exp(-((times - 0.025) / 4e-3) ** 2)
    model = SimpleNamespace(frequencies=np.array([1e3, 3e3, 5e3, 9e3]))
    return SimpleNamespace(capture=SimpleNamespace(times=times, voltages=voltages),
                           plan=SimpleNamespace(focus_time=0.025, modes=np.array([0, 1, 2]), sample_rate=fs),
                           metrics=SimpleNamespace(peak_voltage=1.0), decomposition=SimpleNamespace(model=model),
                           focus_velocity=voltages[:3].sum(axis=0) * 1e-3)


def test_a_one_panel_picture_draws_on_the_given_axes_and_writes_no_file(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    shot = fake_shot()
    fig = Figure()
    volts, spectrum, needed = fig.subplots(3, 1)
    assert report.plot_voltages(shot, tmp_path / "v.png", ax=volts) is volts  # given ax, the path goes unused
    assert report.plot_spectrogram(shot, shot.focus_velocity, shot.plan.sample_rate, 0.024, ax=spectrum) is spectrum
    assert report.plot_modes_needed([1, 2, 3], {"6 mm": np.array([1.0, 0.5, 0.1])}, {"6 mm": [0, 1]},
                                    title="modes", ax=needed) is needed
    assert len(volts.lines) == 4 and volts.get_ylabel() == "voltage (V)"  # three actuators and T_F
    assert spectrum.collections and spectrum.get_ylabel() == "frequency (kHz)"
    assert len(needed.patches) >= 3 and needed.get_title() == "modes"
    assert len(fig.axes) == 4  # the spectrogram's colour bar beside its panel, nothing else added
    assert list(tmp_path.iterdir()) == []


def test_without_axes_a_one_panel_picture_saves_its_own_figure(tmp_path):
    shot = fake_shot()
    path = report.plot_voltages(shot, tmp_path / "v.png")
    assert path == tmp_path / "v.png" and path.read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(ValueError, match="path .* or ax"):
        report.plot_voltages(shot)


def test_the_largest_velocity_at_each_instant_is_read_a_block_of_points_at_a_time():
    """The space-time picture's envelopes and the margin's, without a copy of the field: the copy's."""
    from modalctl.model.metrics import Extremes, largest_each_instant, margin_ratio

    field = np.random.default_rng(1).standard_normal((1000, 37)).astype(np.float32)
    rows = np.flatnonzero(np.arange(1000) % 3 != 0)
    assert np.array_equal(largest_each_instant(field, rows), np.abs(field[rows]).max(axis=0))
    assert np.array_equal(largest_each_instant(field, rows[:0]), np.zeros(37, np.float32))
    mask = np.arange(1000) % 3 == 0
    extremes = Extremes.of(field, mask)
    assert np.array_equal(extremes.inside, np.abs(field[mask]).max(axis=0))
    assert np.array_equal(extremes.outside, np.abs(field[~mask]).max(axis=0))
    times = np.arange(37) * 1e-4
    given = margin_ratio(field, times, 2e-3, mask, outside=extremes.outside)
    i, j = np.unravel_index(np.argmax(np.abs(field[~mask])), (rows.size, 37))  # the whole off-target block at once
    assert given == margin_ratio(field, times, 2e-3, mask) and given[1] == (rows[i], times[j])
    assert given[0] == np.abs(field[~mask]).max() / np.abs(field[:, 20]).max()


RUN = ["run", "--scene", "thesis-al-cc", "--points", "351", "--shape", "sinc", "--param", "width=18mm",
       "--param", "center=24mm", "--focus-time", "25ms", "--modes", "9", "--quiet"]


def test_a_run_draws_its_pictures_beside_its_fields_and_says_what_stopped_them(capsys, tmp_path, monkeypatch):
    """Drawn in a child process while the fields are written; a picture that fails is said on
    stderr without a traceback, the shot's metrics and fields kept, the child's traceback on file."""
    from modalctl.cli import main

    assert main([*RUN, "--out", str(tmp_path / "drawn"), "--json"]) == 0
    metrics = json.loads(capsys.readouterr().out)
    assert metrics["stages_s"]["pictures_s"] > 0 and metrics["stages_s"]["pictures_wait_s"] >= 0
    assert all((tmp_path / "drawn" / f"{name}.png").stat().st_size > 10_000 for name in metrics["pictures"])
    assert set(metrics["pictures"]) == {"spacetime", "modal_bars", "voltages", "spectrogram"}  # both children's

    def broken(shot, out, chosen=None):
        raise ValueError("out of ink")

    monkeypatch.setattr(report, "write_run_report", broken)
    capsys.readouterr()
    assert main([*RUN, "--out", str(tmp_path / "broken")]) == 0  # the shot and its measurement stand
    said = capsys.readouterr().err
    assert "the pictures could not be drawn (ValueError: out of ink)" in said and "Traceback" not in said
    kept = json.loads((tmp_path / "broken" / "metrics.json").read_text())
    assert kept["pictures_error"] == "ValueError: out of ink" and "pictures" not in kept and kept["tau"] > 0.9
    said_on_file = (tmp_path / "broken" / "pictures-error.txt").read_text()
    assert "Traceback" in said_on_file and said_on_file.count("pictures failed") == 2  # both children's, not the first's
    assert (tmp_path / "broken" / "fields.npz").exists() and not list((tmp_path / "broken").glob("*.png"))


def test_an_fe_plate_draws_each_mode_on_a_tile_of_its_own_pixels_with_its_patches_and_sensors(tmp_path):
    """Issue 36: the FE plate's shapes as tiles of one image (not an Axes per mode: 254 modes took 12 s), the
    grid's pixels as they are, the shape's sign right side up, patches outlined and sensors dotted in black."""
    from PIL import Image

    from modalctl.model.fe_convergence import Convergence, Level
    from modalctl.model.modes import Grid, ModalModel

    grid = Grid.rectangle((-0.1, 0.1), (-0.05, 0.05), 81, 41, 1.0)
    x, y = grid.points.T
    shapes = np.array([np.cos(np.pi * x / 0.2) * np.cos(np.pi * y / 0.1), np.sin(np.pi * y / 0.1) + 0 * x])
    shapes /= np.sqrt(shapes ** 2 @ grid.mass)[:, None]
    meta = {"actuators": [{"xlim_m": [-0.0812, -0.0612], "ylim_m": [0.0188, 0.0388]}],  # pixels 8-15 across, 28-35 up
            "sensors": [{"position_m": [0.0488, -0.0012]}]}  # pixel 60 across, 20 up
    model = ModalModel(grid, [300.0, 700.0], [0.01, 0.01], shapes, meta=meta)
    levels = [Level(0.004, 900, np.array([301.0, 703.0]), 1.0), Level(0.002, 3500, np.array([300.0, 700.0]), 3.0)]
    convergence = Convergence(levels, np.array([1e-4, 2e-4]), np.ones(2), 5e-3, True)
    stem = tmp_path / "plate"
    paths = [report.plot_fe_shapes(model, stem), report.plot_fe_convergence(model, convergence, stem)]
    assert paths == [str(tmp_path / "plate_shapes.png"), str(tmp_path / "plate_convergence.png")]
    image = np.asarray(Image.open(paths[0]).convert("RGB")).astype(int)
    assert image.shape == (30 + 41 + 16, 2 * (81 + 6), 3)  # title, then a row of two tiles of 81 x 41 pixels
    tile = lambda k, i, j: image[30 + 16 + 40 - i, k * 87 + j]  # noqa: E731 (tile k's pixel i up, j across)
    red, blue = lambda rgb: rgb[0] > rgb[2] + 50, lambda rgb: rgb[2] > rgb[0] + 50  # noqa: E731
    assert red(tile(0, 20, 40)) and not red(tile(0, 20, 0)) and red(tile(1, 30, 20)) and blue(tile(1, 10, 20))
    assert (tile(0, 31, 8) == 0).all() and (tile(1, 35, 12) == 0).all() and not (tile(1, 31, 12) == 0).all()  # outlined
    assert (tile(0, 20, 60) == 0).all() and (tile(1, 21, 61) == 0).all() and not (tile(0, 20, 63) == 0).all()  # dotted
    assert Image.open(paths[1]).size[0] > 1000


def test_a_closed_loop_of_many_modes_names_those_of_the_largest_references(tmp_path, monkeypatch):
    """A plate's 50 modes in one legend hid the curves (a tablet's 254 took seconds to place): the ten of
    the largest planned envelopes are named, each in a colour of its own; the others are drawn, grey."""
    from modalctl.loops.recorder import Recorder
    from modalctl.loops.runtime import log_fields

    k, periods = 30, 40
    log = tmp_path / "log.json"
    recorder = Recorder(log, log_fields(k, 2), meta={"control_rate_hz": 20e3, "modes": [str(m + 1) for m in range(k)]})
    size = np.random.default_rng(3).permutation(k) + 1.0  # each mode's planned envelope grows to its own size
    for n in range(periods):
        reference = size * n / periods
        recorder.write(period=n, state=2, reference=reference, measured=0.9 * reference, command=0.1 * reference,
                       fraction=1.0, phasor_sum=np.zeros(2), compute=0.0)
    recorder.close()
    drawn = []
    monkeypatch.setattr(report, "_save", lambda fig, path: drawn.append(fig) or path)
    report.plot_loop(log, tmp_path / "loop.png")
    envelopes = drawn[0].axes[0]
    named = [text.get_text() for text in envelopes.get_legend().get_texts()]
    assert sorted(named) == sorted(f"mode {m + 1}" for m in np.argsort(-size)[:report.NAMED_MODES])
    colours = [line.get_color() for line in envelopes.get_legend().get_lines()]
    assert len(set(colours)) == report.NAMED_MODES
    assert len(envelopes.lines) == 2 * k and f"the {k - report.NAMED_MODES} modes" in envelopes.get_title()
