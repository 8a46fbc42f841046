"""The simulator's truth scenarios: resonances moving during the shot, a finger resting on the surface."""

import json

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from modalctl.cli import main
from modalctl.hil.finger import FingerPlant
from modalctl.hil.scenario import Perturbation
from modalctl.hil.sim_device import SimDevice
from modalctl.model.scenes import load_scene
from modalctl.model.touch import Touch

RUN = ["run", "--scene", "thesis-al-cc", "--points", "211", "--shape", "sinc", "--param", "width=18mm",
       "--param", "center=24mm", "--focus-time", "25ms", "--quiet", "--no-plots", "--json"]


def _play(model, perturbation, u, fs):
    device = SimDevice(model, perturbation, hold="foh")
    device.configure(fs)
    device.activate()
    device.upload(u)
    device.trigger()
    return device.modal_truth()


def test_moving_resonances_match_an_independent_integration_of_the_time_varying_modes():
    """A ramp of every resonance (2 per second) and a 1% step at 4 ms against scipy's DOP853 on
    ``eta'' + 2 zeta w(t) eta' + w(t)^2 eta = B u(t)``, the drive interpolated as the DAC's
    first-order hold plays it. The simulator holds each resonance over 50 us and switches it on
    a sample, so it agrees to O(dw dt): 3.5e-3 here at 200 kHz; without the drift it is off by 130%."""
    model = load_scene("thesis-al-cc", 105).select(np.arange(5))
    fs, n = 200e3, 2000
    t = np.arange(n) / fs
    u = np.zeros((8, n))
    u[0], u[3] = np.sin(model.omega[1] * t), np.sin(model.omega[4] * t)
    drift = Perturbation(drift_rate=2.0, drift_step=0.01, drift_step_time=4e-3)
    kept, velocity = _play(model, drift, u, fs)
    k, b = kept.size, model.actuator_gains[kept]

    def rhs(time, y):
        w = model.omega[kept] * (1 + drift.shift(time))
        force = b @ np.array([np.interp(time, t, row) for row in u])
        return np.r_[y[k:], force - 2 * model.damping[kept] * w * y[k:] - w ** 2 * y[:k]]

    exact = solve_ivp(rhs, (0, t[-1]), np.zeros(2 * k), t_eval=t, method="DOP853", rtol=1e-9, atol=1e-12,
                      max_step=1 / fs).y[k:]
    scale = np.max(np.abs(exact))
    assert np.max(np.abs(velocity - exact)) < 5e-3 * scale
    still = _play(model, Perturbation(), u, fs)[1]
    assert np.max(np.abs(still - exact)) > 0.3 * scale


def test_the_device_plays_the_finger_where_it_rests():
    model = load_scene("thesis-al-cc", 105)
    at = model.grid.points[30]
    u = np.random.default_rng(2).standard_normal((8, 500))
    _, velocity = _play(model, Perturbation(finger=0.5, finger_at=tuple(at)), u, 200e3)
    direct = FingerPlant(model, Touch(30, 0.5), 200e3, hold="foh").step(u)
    assert np.allclose(velocity, direct, rtol=0, atol=1e-12 * np.max(np.abs(direct)))
    assert np.max(np.abs(_play(model, Perturbation(), u, 200e3)[1] - direct)) > 1e-2 * np.max(np.abs(direct))


@pytest.mark.parametrize("options, words", [
    ({"finger": 0.5}, "needs a place to rest"),
    ({"finger": -1.0, "finger_at": (0.0,)}, "zero or more"),
    ({"finger": 0.5, "finger_at": (0.0,), "drift_rate": 1.0}, "not simulated"),
    ({"drift_step": 0.01, "amplifier_bandwidth": 1e5}, "amplifier's bandwidth")])
def test_scenarios_the_simulator_cannot_play_are_refused(options, words):
    with pytest.raises(ValueError, match=words):
        Perturbation(**options)


@pytest.mark.slow
def test_run_with_a_finger_and_a_drift_ramp_open_and_closed(capsys, tmp_path):
    """A finger (0.5 N s/m at the focus) and a ramp (+1% by the focus): the truth says what it was,
    and the loops recover focus the open loop loses."""
    taus = {}
    cases = {"finger": (["--finger", "0.5Ns/m"], "finger 0.5 N s/m at 24 mm"),
             "ramp": (["--drift-rate", "40%/s"], "drift +40%/s")}
    for case, (truth, described) in cases.items():
        for loop in ("open", "closed"):
            assert main([*RUN, *truth, "--loop", loop, "--out", str(tmp_path / f"{case}-{loop}")]) == 0
            metrics = json.loads(capsys.readouterr().out)
            taus[case, loop] = metrics["tau"]
            assert metrics["truth"] == described
    assert taus["finger", "open"] < 0.8 and taus["finger", "closed"] > taus["finger", "open"] + 0.1
    assert taus["ramp", "open"] < 0.9 and taus["ramp", "closed"] > 0.95


@pytest.mark.parametrize("args, code, words", [
    (["--finger-at", "24mm"], 2, "--finger-at places a finger"),
    (["--finger", "0.5Ns/m", "--finger-at", "90mm"], 2, "off the structure"),
    (["--finger", "0.5Ns/m", "--finger-at", "1mm,2mm"], 2, "2 coordinate(s) on a 1-D structure"),
    (["--finger", "0.5Ns/m", "--drift-step", "1%@10ms"], 2, "not simulated"),
])
def test_finger_and_drift_options_refused_with_a_reason(capsys, tmp_path, args, code, words):
    assert main([*RUN, *args, "--out", str(tmp_path / "r")]) == code
    assert words in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("value, words", [("1%", "expected SHIFT@TIME"), ("1%@-2ms", "must lie in [0"),
                                          ("1kg@2ms", "unknown unit")])
def test_a_malformed_drift_step_exits_2(capsys, tmp_path, value, words):
    with pytest.raises(SystemExit) as exit_:
        main([*RUN, "--drift-step", value, "--out", str(tmp_path)])
    assert exit_.value.code == 2 and words in capsys.readouterr().err


def test_negative_values_with_units_read_as_values():
    """argparse alone takes ``--drift -1%`` for an unknown option (it knows only bare negative numbers)."""
    from modalctl.cli import _negatives_attached, build_parser

    argv = [*RUN, "--drift", "-1%", "--finger", "1Ns/m", "--finger-at", "-30mm", "--param", "center=-24mm",
            "--out", "x"]
    args = build_parser().parse_args(_negatives_attached(argv))
    assert args.drift == -0.01 and args.finger_at == (-0.03,) and ("center", "-24mm") in args.param
    assert args.quiet and args.json  # flags next to it untouched


def test_a_run_under_a_finger_draws_its_report(capsys, tmp_path):
    """The space-time picture marks where the finger rests (look at it: a dotted line, named)."""
    args = [a for a in RUN if a != "--no-plots"]
    assert main([*args, "--finger", "0.5Ns/m", "--finger-at", "-20mm", "--out", str(tmp_path)]) == 0
    pictures = json.loads(capsys.readouterr().out)["pictures"]
    assert (tmp_path / "spacetime.png").stat().st_size > 10_000 and "spacetime" in pictures


def test_the_vibrometer_averages_its_repeats():
    """Sixteen repeats of each point: the scan's noise about the truth falls by four (the sensors' not)."""
    model = load_scene("thesis-al-cc", 105).select(np.arange(5))
    fs, n = 200e3, 2000
    u = np.zeros((8, n))
    u[0] = np.sin(model.omega[1] * np.arange(n) / fs)
    spread = []
    for repeats in (1, 16):
        device = SimDevice(model, Perturbation(snr_db=30.0, scan_repeats=repeats))
        device.configure(fs)
        device.activate()
        device.upload(u)
        device.trigger()
        kept, velocity = device.modal_truth()
        times = np.arange(0, n, 5) / fs
        truth = model.shapes[kept].T @ velocity[:, ::5]
        spread.append(np.std(device.scan(times) - truth))
    assert spread[0] / spread[1] == pytest.approx(4.0, rel=0.1)
    with pytest.raises(ValueError, match="scan_repeats"):
        Perturbation(scan_repeats=0)
