"""Identification: estimators against analytic FRFs, resolution limits, and the HIL survey end to end."""

import re
import warnings

import numpy as np
import pytest

from modalctl.hil.scenario import Perturbation
from modalctl.hil.sim_device import SimDevice
from modalctl.identify.estimators import peak_picking, sdof_fit
from modalctl.identify.frf import FRF, SpatialAliasingWarning, Sweep, check_spatial_step, read_uff58
from modalctl.identify.survey import beam_wavelength, identify_device
from modalctl.model.modes import ModelError
from modalctl.model.scenes import load_scene
from modalctl.options import SurveyOptions
from modalctl.plugin.manager import identifiers

X = np.linspace(0, 0.1, 41)


def analytic_frf(freqs_hz, modes, snr_db=None, averages=4, seed=0):
    """Mobility sum_k A_k(x) j w / (w_k^2 - w^2 + 2 j zeta_k w_k w), with complex noise whose
    level is the FRF's peak over 10^(snr/20) divided by sqrt(averages)."""
    w = 2 * np.pi * freqs_hz
    h = np.zeros((X.size, w.size), complex)
    for f, zeta, shape in modes:
        wk = 2 * np.pi * f
        h += np.outer(shape, 1j * w / (wk**2 - w**2 + 2j * zeta * wk * w))
    coherence, std = np.ones(h.shape), None
    if snr_db is not None:
        rng = np.random.default_rng(seed)
        sigma = np.abs(h).max() / 10 ** (snr_db / 20) / np.sqrt(averages)
        noise = sigma * (rng.standard_normal(h.shape) + 1j * rng.standard_normal(h.shape)) / np.sqrt(2)
        coherence = np.abs(h) ** 2 / (np.abs(h) ** 2 + averages * sigma**2)
        h, std = h + noise, np.full(h.shape, sigma)
    return FRF(freqs_hz, h, coherence, X[:, None], 0, averages, 0.0, std)


def mac(a, b):
    return (a @ b) ** 2 / ((a @ a) * (b @ b))


TWO_MODES = [(1000.0, 0.01, 50 * np.sin(np.pi * X / 0.1)), (2500.0, 0.02, 80 * np.sin(2 * np.pi * X / 0.1))]


@pytest.mark.parametrize("estimator", [peak_picking, sdof_fit])
def test_estimators_recover_separated_modes(estimator):
    freqs = np.arange(200, 4000, 1.0)
    modes = estimator(analytic_frf(freqs, TWO_MODES, snr_db=40))
    assert modes.n_modes == 2 and modes.resolved.all()
    for (f, zeta, shape), fi, zi, ci in zip(TWO_MODES, modes.frequencies, modes.damping, modes.constants):
        assert abs(fi / f - 1) < 5e-4
        assert abs(zi / zeta - 1) < 0.05
        assert mac(ci, shape) > 0.99
        assert np.allclose(ci, shape, rtol=0.05, atol=0.05 * np.abs(shape).max())  # scale and sign (Eq 3.9)


def test_sdof_is_more_accurate_on_a_coarse_frf():
    """With 1.3 bins per half-power band, the half-power rule errs by about 5% on damping; the local fit
    stays within 0.1%."""
    freqs = np.arange(200, 4000, 15.0)
    truth = TWO_MODES[0]
    peaks, sdof = (m(analytic_frf(freqs, TWO_MODES, snr_db=60)) for m in (peak_picking, sdof_fit))
    err = [abs(m.damping[0] / truth[1] - 1) for m in (peaks, sdof)]
    assert err[1] < 1e-3 and err[0] > 0.02


@pytest.mark.parametrize("estimator", [peak_picking, sdof_fit])
def test_close_modes_are_reported_unresolved(estimator):
    """Two modes 0.5 half-power bandwidths apart, with different shapes: never one clean mode."""
    zeta = 0.01
    close = [(1000.0, zeta, 50 * np.sin(np.pi * X / 0.1)), (1000.0 * (1 + zeta), zeta, 50 * np.sin(3 * np.pi * X / 0.1))]
    modes = estimator(analytic_frf(np.arange(500, 1500, 0.5), close, snr_db=40))
    near = np.abs(modes.frequencies - 1005) < 30
    assert near.any()
    assert not modes.resolved[near].any()


def test_a_coarse_grid_warns():
    truth = load_scene("thesis-al-cc", 211)
    with pytest.warns(SpatialAliasingWarning):
        check_spatial_step(truth.grid.points[::20], beam_wavelength(truth.meta, 100e3))


def test_sweep_rules():
    with pytest.raises(ModelError, match="ten times"):
        Sweep(100, 100e3, 0.25, 500e3)
    s = Sweep.design(100, 10e3, 4.0)
    assert s.sample_rate == 100e3 and s.duration == 0.25
    assert abs(s.resolution - 4.0) < 0.3  # the tail lengthens the record a little
    with pytest.warns(SpatialAliasingWarning):
        check_spatial_step(np.arange(0, 0.1, 0.005), wavelength=0.008)


def test_h1_matches_the_analytic_mobility():
    """HIL shot -> H1 against the model's mobility computed independently, times the first-order
    hold's sinc^2 (the DAC's linear interpolation between samples). What is left (0.1% of the
    peak) is the response to the hold's spectral images near fs - f, aliased back by sampling."""
    from modalctl.identify.acquire import measure_frf

    model = load_scene("thesis-al-cc", 211)
    device = SimDevice(model, Perturbation(), hold="foh")
    sweep = Sweep.design(100, 3e3, 4.0, slowest_decay=27.0)  # mode 1 decays at zeta w = 27/s: no leakage
    device.configure(sweep.sample_rate)
    device.activate()
    points = np.array([30, 100, 150])
    frf = measure_frf(device, sweep, 2, points, averages=1)
    w = 2 * np.pi * frf.frequencies
    wk, zk = model.omega[:, None], model.damping[:, None]
    expected = (model.shapes[:, points].T * model.actuator_gains[:, 2]) @ (1j * w / (wk**2 - w**2 + 2j * zk * wk * w))
    expected = expected * np.sinc(frf.frequencies / sweep.sample_rate) ** 2
    band = (frf.frequencies > 200) & (frf.frequencies < 2000)
    err = np.abs(frf.values[:, band] - expected[:, band]) / np.abs(expected[:, band]).max()
    assert err.max() < 2e-3


@pytest.fixture(scope="module")
def survey():
    """The HIL beam identified from scratch, modes up to 12 kHz, on every 5th point (2.5 mm)."""
    truth = load_scene("thesis-al-cc", 211)
    device = SimDevice(truth, Perturbation(snr_db=40, seed=3))
    points = np.arange(0, truth.grid.n, 5)
    mass = truth.meta["density_kg_m3"] * truth.meta["width_m"] * truth.meta["thickness_m"]
    with warnings.catch_warnings():
        warnings.simplefilter("error", SpatialAliasingWarning)
        return truth, points, identify_device(device, Sweep.design(100, 12e3, 4.0), points, mass,
                                              SurveyOptions(sparse=4), beam_wavelength(truth.meta, 12e3))


def test_survey_identifies_the_hil_beam(survey):
    """Frequencies, damping, shapes and every actuator's gains against the truth."""
    truth, points, result = survey
    model = result.model
    assert model.n_modes == 7
    assert np.allclose(model.frequencies, truth.frequencies[:7], rtol=5e-4)
    assert np.allclose(model.damping, truth.damping[:7], rtol=0.05)
    for k in range(7):
        phi = truth.shapes[k, points]
        assert mac(model.shapes[k], phi) > 0.99
        sign = np.sign(model.shapes[k] @ phi)
        g, gt = model.actuator_gains[k], sign * truth.actuator_gains[k]
        assert np.linalg.norm(g - gt) < 0.05 * np.linalg.norm(gt)
    # mode 5 barely moves under actuator 0 (the thesis's mode-18 situation): found through the others
    found = [re.match(r"mode at ([\d.]+) Hz: actuator 0 drives it", note) for note in result.notes]
    assert any(abs(float(m.group(1)) - truth.frequencies[4]) < 5e-4 * truth.frequencies[4] for m in found if m)


def test_focus_with_the_identified_model(survey):
    """The closed cycle: the HIL beam focused with its identified model does as well as with the truth."""
    from modalctl.model.shape import parse_params
    from modalctl.options import PlanOptions, RunOptions
    from modalctl.plugin.manager import get_shape
    from modalctl.run import run

    truth, points, result = survey
    with warnings.catch_warnings():  # the scan's 2.5 mm step draws only the first 18 of the scene's 21 modes
        warnings.simplefilter("ignore")
        same_grid = load_scene("thesis-al-cc", points.size)
    sinc = get_shape("sinc")
    taus = []
    for model in (result.model, same_grid):
        shape = sinc.generate(model.grid, **parse_params(sinc, {"width": "25mm", "center": "24mm"}))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            taus.append(run(model, shape, SimDevice(truth), RunOptions(0.025, PlanOptions(modes=6))).metrics.tau)
    assert taus[1] > 0.95
    assert abs(taus[0] - taus[1]) < 0.02


def test_identifier_plugins_are_registered():
    assert {"peaks", "sdof"} <= set(identifiers())


def test_uff58_round_trip(tmp_path):
    """FRFs written as UFF 58 with pyuff (and nodes as UFF 15) read back and identify the same modes."""
    pyuff = pytest.importorskip("pyuff")
    freqs = np.arange(200, 4000, 1.0)
    frf = analytic_frf(freqs, TWO_MODES)
    path = tmp_path / "beam.uff"
    uff = pyuff.UFF(str(path))
    nodes = np.arange(1, X.size + 1)
    uff.write_sets(pyuff.prepare_15(node_nums=nodes, x=X, y=np.zeros(X.size), z=np.zeros(X.size)), mode="add")
    for node, row in zip(nodes, frf.values):
        uff.write_sets(pyuff.prepare_58(func_type=4, rsp_node=int(node), rsp_dir=3, ref_node=100, ref_dir=3,
                                        data=row, x=freqs, id1="mobility", rsp_ent_name="beam", ref_ent_name="beam",
                                        abscissa_spacing=1, abscissa_spec_data_type=18, ordinate_spec_data_type=11,
                                        orddenom_spec_data_type=13), mode="add")
    back = read_uff58(path)
    assert np.allclose(back.frequencies, freqs) and np.allclose(back.points[:, 0], X)
    assert np.allclose(back.values, frf.values, rtol=1e-6, atol=1e-9 * np.abs(frf.values).max())
    modes = sdof_fit(back)
    assert np.allclose(modes.frequencies, [1000, 2500], rtol=1e-5)
    from modalctl.identify.survey import identify_frf

    model = identify_frf(back, density=1.9).model
    assert model.n_modes == 2 and all(mac(model.shapes[k], s[2]) > 0.999 for k, s in enumerate(TWO_MODES))


def test_identify_cli_on_the_hil_and_bad_input(tmp_path):
    from modalctl.cli import main

    out = tmp_path / "beam.npz"
    code = main(["identify", "--scene", "thesis-al-cc", "--f-high", "6kHz", "--step", "2mm", "--out", str(out),
                 "--quiet", "--no-plots", "--json"])
    assert code == 0
    from modalctl.model.modes import ModalModel

    model = ModalModel.load(out)
    assert model.n_modes == 5 and model.actuator_gains.shape == (5, 8)
    # the README's flow: the identified model planned on, the scene as the truth (issue 26: it exited 2,
    # the model having no sensors); open loop plays, a closed loop is refused saying why
    run = ["run", "--model", str(out), "--truth", "thesis-al-cc", "--shape", "sinc", "--param", "width=25mm",
           "--param", "center=24mm", "--focus-time", "25ms", "--modes", "all", "--margin", "none", "--quiet",
           "--no-plots"]
    assert main([*run, "--out", str(tmp_path / "open")]) == 0
    import json

    metrics = json.loads((tmp_path / "open" / "metrics.json").read_text())
    assert metrics["tau"] > 0.9 and metrics["modes_used"] == [1, 2, 3, 4, 5]
    assert main([*run, "--loop", "closed", "--out", str(tmp_path / "closed")]) == 2
    assert main(["identify", "--out", str(out)]) == 2  # the simulator needs a scene
    assert main(["identify", "--scene", "thesis-al-cc", "--f-high", "6kHz", "--method", "nope",
                 "--out", str(out)]) == 2


@pytest.mark.parametrize("args, words", [
    (["--scene", "plate-glass", "--mass-per-length", "1kg/m"], "on a plate: give --mass-per-area"),
    (["--scene", "plate-glass", "--step", "30mm"], "at least 5 per direction"),
    (["--scene", "thesis-al-cc", "--primary", "99"], "primary actuator 99: the device has 8 (0..7)"),
    (["--scene", "thesis-al-cc", "--resolution", "0Hz"], "resolution must lie in (0, 10000]"),
    (["--scene", "thesis-al-cc", "--step=-1mm"], "step must lie in (0, inf)"),
])
def test_identify_refuses_what_it_cannot_do(capsys, tmp_path, args, words):
    from modalctl.cli import main

    try:
        code = main(["identify", *args, "--f-high", "6kHz", "--out", str(tmp_path / "m.npz"), "--quiet", "--no-plots"])
    except SystemExit as exit_:  # argparse's own refusals
        code = exit_.code
    assert code == 2 and words in capsys.readouterr().err and not (tmp_path / "m.npz").exists()


def test_repeated_shots_have_their_own_noise_and_the_frf_knows_its_scatter():
    """Averages average on the HIL (each trigger its own vibrometer noise, the same drive or not),
    and the H1 noise estimate from the scatter between shots matches the difference of two
    independent estimates (whose standard deviation is sqrt(2) times it)."""
    from modalctl.identify.acquire import measure_frf

    truth = load_scene("thesis-al-cc")
    sweep = Sweep.design(100, 6e3, 4.0)
    device = SimDevice(truth, Perturbation(snr_db=30, seed=3))
    device.configure(sweep.sample_rate)
    device.activate()
    points = np.arange(0, truth.grid.n, 50)
    a = measure_frf(device, sweep, 0, points, averages=3)
    b = measure_frf(device, sweep, 0, points, averages=3)
    assert np.all(a.noise_std > 0)
    ratio = np.sqrt(np.mean(np.abs(a.values - b.values) ** 2) / np.mean(a.noise_std**2 + b.noise_std**2))
    assert 0.8 < ratio < 1.25  # the difference of two estimates: variance the sum of theirs


def test_plate_identified_end_to_end_then_focused_with_its_model(tmp_path):
    """``modalctl identify --scene plate-glass`` (the survey on a 2-D grid, every actuator), then
    ``run --model`` with a 2-D shape on the identified model, the scene as the truth."""
    import json

    from modalctl.cli import main
    from modalctl.model.modes import ModalModel

    out = tmp_path / "plate.npz"
    assert main(["identify", "--scene", "plate-glass", "--f-low", "300Hz", "--f-high", "3.5kHz", "--step", "10mm",
                 "--out", str(out), "--quiet", "--no-plots", "--json"]) == 0
    model, truth = ModalModel.load(out), load_scene("plate-glass")
    assert model.grid.dim == 2 and model.grid.shape == (11, 8) and model.actuator_gains.shape == (5, 4)
    assert np.allclose(model.frequencies, truth.frequencies[:5], rtol=1e-4)
    index = [int(np.argmin(np.sum((truth.grid.points - p) ** 2, axis=1))) for p in model.grid.points]
    for k in range(5):
        assert mac(model.shapes[k], truth.shapes[k, index]) > 0.99
    # gains: each patch's drive of each mode against the scene's (mass-normalized shapes; a shape's
    # sign is a convention, the field a volt makes, gain times shape, is not)
    sign = np.sign([model.shapes[k] @ truth.shapes[k, index] for k in range(5)])[:, None]
    assert np.allclose(sign * model.actuator_gains, truth.actuator_gains[:5], rtol=0.05,
                       atol=0.02 * np.abs(truth.actuator_gains[:5]).max())
    focus = ["--shape", "gaussian", "--param", "width=40mm", "--focus-time", "25ms", "--modes", "5", "--margin",
             "none", "--quiet", "--no-plots"]
    assert main(["run", "--model", str(out), "--truth", "plate-glass", *focus, "--out", str(tmp_path / "model")]) == 0
    tau = json.loads((tmp_path / "model" / "metrics.json").read_text())["tau"]
    # the scene's own five modes on the same 11 x 8 points focus as well (a 40 mm Gaussian wants more modes)
    assert main(["run", "--scene", "plate-glass", "--points", "11x8", *focus, "--out", str(tmp_path / "scene")]) == 0
    assert abs(tau - json.loads((tmp_path / "scene" / "metrics.json").read_text())["tau"]) < 0.03


def test_identify_draws_no_bars_into_a_log_and_says_its_stage(tmp_path, capsys):
    """stderr not a terminal (capsys: a log): one line for the survey, no carriage-return frames;
    the simulator's vibrometer still at its 40 dB when --snr is not given."""
    import json

    from modalctl.cli import identify, main

    seen = []
    real = identify.open_device

    def spy(args, scene):
        seen.append(args.snr)
        return real(args, scene)

    identify.open_device = spy
    try:
        code = main(["identify", "--scene", "thesis-al-cc", "--f-high", "6kHz", "--step", "2mm", "--no-plots",
                     "--json", "--out", str(tmp_path / "m.npz")])
    finally:
        identify.open_device = real
    captured = capsys.readouterr()
    assert code == 0 and json.loads(captured.out)["modes"] == 5
    assert "\r" not in captured.err and "modalctl identify: the survey: 100 to 6000 Hz" in captured.err
    assert seen == [identify.SNR]


@pytest.mark.parametrize("out, words", [("/proc/modalctl-x/m.npz", "kernel's proc"), ("", "give a file name")])
def test_identify_out_is_checked_by_its_type_before_any_work(capsys, out, words):
    from modalctl.cli import main

    with pytest.raises(SystemExit) as refused:
        main(["identify", "--scene", "thesis-al-cc", "--out", out])
    err = capsys.readouterr().err
    assert refused.value.code == 2 and "argument --out: " in err and words in err
