"""The survey's fast paths (issue 39) against the slower ones they replace: the simulator's scan
spectrum against the FFT of its scan, grouped FRFs against one group, the randomized principal FRFs
against the whole Gram matrix's, and the identified plate against its scene and the record path."""

from dataclasses import replace

import numpy as np
import pytest

from modalctl.hil.scenario import Perturbation
from modalctl.hil.sim_device import SimDevice
from modalctl.identify import acquire, lscf
from modalctl.identify.acquire import measure_frf
from modalctl.identify.frf import Sweep
from modalctl.identify.survey import identify_device, mac, scan_subset
from modalctl.model.scenes import load_scene
from modalctl.options import SurveyOptions


class RecordsOnly:
    """A device that gives its scan's records only (as a board would): the FRFs' slower path."""

    def __init__(self, device):
        self._device = device

    def __getattr__(self, name):
        if name == "scan_spectrum":
            raise AttributeError(name)
        return getattr(self._device, name)


def _device(scene: str, snr=None, seed=3, rate=None):
    device = SimDevice(load_scene(scene), Perturbation(snr_db=snr, seed=seed))
    if rate is not None:
        device.configure(rate)
        device.activate()
    return device


def test_scan_spectrum_is_the_fft_of_the_scan_and_its_noise_has_the_dft_statistics():
    """Noise-free: the spectrum the simulator makes from its modes' spectra equals the rfft of its
    scan (to the scan's float32); noisy: each bin's noise has variance n sigma^2, real at DC."""
    sweep = Sweep.design(100, 6e3, 4.0)
    device = _device("thesis-al-cc", rate=sweep.sample_rate)
    wave = np.zeros((device.capabilities.channels, sweep.samples))
    wave[1] = sweep.waveform()
    device.upload(wave)
    capture = device.trigger()
    points = np.array([3, 40, 77, 100])
    bins = slice(10, 2000)
    record = np.fft.rfft(device.scan(capture.times, points).astype(float), axis=-1)[:, bins]
    spectrum = device.scan_spectrum(bins, points)
    assert np.abs(spectrum - record).max() < 1e-5 * np.abs(record).max()

    noisy = _device("thesis-al-cc", snr=20, rate=sweep.sample_rate)
    noisy.upload(wave)
    noisy.trigger()
    bins = slice(0, 4000)
    many = np.arange(0, noisy.capabilities.scan_points.shape[0], 2)
    noise = noisy.scan_spectrum(bins, many) - device.scan_spectrum(bins, many)
    n, sigma = sweep.samples, noisy._noise_sigma
    assert abs(np.mean(np.abs(noise[:, 1:]) ** 2) / (n * sigma**2) - 1) < 0.02
    assert np.all(noise[:, 0].imag == 0) and abs(np.mean(noise[:, 0].real ** 2) / (n * sigma**2) - 1) < 0.3
    again = noisy.scan_spectrum(bins, many[5:9])  # a point's noise whatever the points asked with it
    assert np.array_equal(again, noisy.scan_spectrum(bins, many)[5:9])


def test_frfs_through_the_spectrum_and_in_groups_equal_those_through_the_records(monkeypatch):
    """measure_frf: the spectrum path against the record path (same shot, noise-free, to float32),
    and points measured a few at a time against all at once (to the last bits BLAS's blocking moves)."""
    sweep = Sweep.design(100, 6e3, 4.0)
    device = _device("thesis-al-cc", rate=sweep.sample_rate)
    points = np.arange(0, device.capabilities.scan_points.shape[0], 9)
    fast = measure_frf(device, sweep, 2, points, averages=2)
    slow = measure_frf(RecordsOnly(device), sweep, 2, points, averages=2)
    assert np.array_equal(fast.frequencies, slow.frequencies)
    assert np.abs(fast.values - slow.values).max() < 1e-6 * np.abs(slow.values).max()
    monkeypatch.setattr(acquire, "GROUP", 5)
    grouped = measure_frf(device, sweep, 2, points, averages=2, batch=2)
    assert np.allclose(grouped.values, fast.values, rtol=1e-12, atol=0) and np.array_equal(grouped.points, fast.points)
    assert np.allclose(grouped.coherence, fast.coherence, rtol=1e-12) and grouped.averages == 2


def test_randomized_principal_frfs_span_the_gram_matrix_s():
    """Above DIRECT_ROWS rows the principal FRFs come from a sketch of the rows' range: the same
    subspace as the whole Gram matrix's eigenvectors give, on rows of a few modes and noise."""
    rng = np.random.default_rng(2)
    rows, bins, modes = 600, 900, 5
    signal = (rng.standard_normal((rows, modes)) * np.geomspace(10, 1, modes)) @ \
        (rng.standard_normal((modes, bins)) + 1j * rng.standard_normal((modes, bins)))
    values = signal + 0.05 * (rng.standard_normal((rows, bins)) + 1j * rng.standard_normal((rows, bins)))
    assert rows > lscf.DIRECT_ROWS
    fast = lscf._principal(values, lscf.COMPONENTS)
    power, u = np.linalg.eigh(values @ values.conj().T)  # the whole Gram matrix, independently
    slow = u[:, ::-1][:, :fast.shape[0]].conj().T @ values
    assert fast.shape[0] == modes
    q_fast, q_slow = np.linalg.qr(fast.T)[0], np.linalg.qr(slow.T)[0]
    assert np.linalg.svd(q_fast.conj().T @ q_slow, compute_uv=False).min() > 1 - 1e-8  # cosines of the angles


@pytest.fixture(scope="module")
def plates():
    """The plate identified on a 3 mm lattice (816 points, 656 sparse FRFs: the randomized
    principal FRFs) up to 3.5 kHz, fast; and by the slower paths (records and FFTs per point, the
    whole Gram matrix), the same shots."""
    sweep = Sweep.design(300, 3.5e3, 4.0)
    truth = load_scene("plate-glass")
    density = truth.meta["density_kg_m3"] * truth.meta["thickness_m"]
    points = scan_subset(truth.grid.points, 3e-3)
    fast = identify_device(_device("plate-glass", snr=40), sweep, points, density, SurveyOptions())
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(lscf, "DIRECT_ROWS", 10**6)
        slow = identify_device(RecordsOnly(_device("plate-glass", snr=40)), sweep, points, density, SurveyOptions())
    return truth, points, fast, slow


def test_the_fast_survey_identifies_the_plate_as_the_slow_one_and_the_scene(plates):
    """Frequencies to 1e-4 of the scene's (the existing plate test's tolerance), damping to 5%,
    shapes MAC above 0.99; and the same modes as the slower paths find (their noise differs)."""
    truth, points, fast, slow = plates
    model = fast.model
    assert model.n_modes == slow.model.n_modes == 5
    assert np.allclose(model.frequencies, truth.frequencies[:5], rtol=1e-4)
    assert np.allclose(model.damping, truth.damping[:5], rtol=0.05)
    assert np.all(mac(model.shapes, truth.shapes[:5, points]) > 0.99)
    assert np.allclose(model.frequencies, slow.model.frequencies, rtol=1e-4)
    assert np.allclose(model.damping, slow.model.damping, rtol=0.05)
    assert np.all(mac(model.shapes, slow.model.shapes) > 0.999)
    assert np.array_equal(fast.shape_actuator, slow.shape_actuator)


def test_the_full_scan_kept_on_the_lines_its_fits_read_gives_the_model_of_every_line(monkeypatch):
    """The full scan keeps the lines :func:`lines_read` names (a fifth of them here): the shapes, gains and
    misfits equal those of the scan kept on every line (the same shots: a noise-free device), to round-off."""
    from modalctl.identify import survey

    sweep = Sweep.design(100, 12e3, 4.0)
    truth = load_scene("thesis-al-cc")
    points = np.arange(0, truth.grid.points.shape[0], 3)
    density = truth.meta.get("mass_per_length_kg_m", 1.0)
    kept = identify_device(_device("thesis-al-cc"), sweep, points, density, SurveyOptions())
    primary = SurveyOptions().primary
    lines = kept.frfs["full"][primary].frequencies.size
    every = kept.frfs["sparse"][primary].frequencies.size
    assert 0 < lines < every / 4  # 620 of 3,124
    monkeypatch.setattr(survey, "lines_read", lambda f, *args: np.ones(np.size(f), bool))
    whole = identify_device(_device("thesis-al-cc"), sweep, points, density, SurveyOptions())
    assert whole.frfs["full"][primary].frequencies.size == every
    assert kept.model.n_modes == whole.model.n_modes >= 5
    for name in ("frequencies", "damping", "shapes", "actuator_gains"):
        assert np.allclose(getattr(kept.model, name), getattr(whole.model, name), rtol=1e-9, atol=0), name
    assert np.allclose(kept.model.meta["misfit"], whole.model.meta["misfit"], rtol=1e-9, atol=0)


def test_the_sparse_frfs_measured_into_one_stack_are_those_measured_apart_and_balanced_back(monkeypatch):
    """Measured into the rows of one FRF (views: no stacked copy), each actuator's FRFs are those measured
    apart (the same noise-free shots); balanced for the poles they are FRF.stack's rows, and after it
    (or an interruption) their measured values again (to rounding); a dead channel's zero FRFs are
    refused, not scaled to NaN. Too little memory for them: refused before a shot."""
    from modalctl.identify import survey
    from modalctl.identify.frf import FRF
    from modalctl.model.modes import ModelError

    sweep = Sweep.design(100, 6e3, 4.0)
    device, alone = _device("thesis-al-cc", rate=sweep.sample_rate), _device("thesis-al-cc", rate=sweep.sample_rate)
    points, order = np.arange(0, device.capabilities.scan_points.shape[0], 9), [1, 2, 0]
    frfs, stacked = survey._sparse_scan(survey._Steps(3, False, None), device, sweep, order, points, 2)
    apart = {a: measure_frf(alone, sweep, a, points, averages=2) for a in order}
    reference = FRF.stack([apart[a] for a in sorted(order)])
    assert list(frfs) == [0, 1, 2] and all(np.shares_memory(f.values, stacked.values) for f in frfs.values())
    assert np.array_equal(stacked.frequencies, reference.frequencies) and stacked.averages == 2
    with survey._balanced(stacked, frfs):  # coherence and noise held in single precision (statistics of 2 shots)
        for name, rtol in (("values", 1e-12), ("noise_std", 1e-6), ("coherence", 1e-6), ("points", 1e-12)):
            assert np.allclose(getattr(stacked, name), getattr(reference, name), rtol=rtol, atol=0), name
    for a in order:
        assert frfs[a].actuator == a and np.allclose(frfs[a].values, apart[a].values, rtol=1e-14, atol=0)
        assert np.allclose(frfs[a].noise_std, apart[a].noise_std, rtol=1e-6, atol=0)
    with pytest.raises(KeyboardInterrupt):  # the poles stopped: the FRFs are still given back as measured
        with survey._balanced(stacked, frfs):
            raise KeyboardInterrupt
    assert all(np.allclose(frfs[a].values, apart[a].values, rtol=1e-13, atol=0) for a in order)
    dead = {0: frfs[0], 1: replace(frfs[1], values=np.zeros_like(frfs[1].values))}
    with pytest.raises(ModelError, match="actuator 1's FRFs are zero"):  # a dead channel: said, nothing scaled
        with survey._balanced(stacked, dead):
            pass
    assert np.allclose(frfs[0].values, apart[0].values, rtol=1e-13, atol=0)
    monkeypatch.setattr(survey, "memory_available", lambda: 10**6)
    with pytest.raises(ModelError, match="memory available"):
        survey._sparse_scan(survey._Steps(3, False, None), device, sweep, order, points, 2)


def test_a_primary_actuator_other_than_the_first_gives_its_summary(tmp_path, capsys):
    """--primary 1: the full scan holds actuator 1's FRFs (and those of the actuators that drive a mode
    better), not actuator 0's; the summary's unit was read from actuator 0's (a KeyError traceback)."""
    import json

    from modalctl.cli import main

    assert main(["identify", "--scene", "thesis-al-cc", "--f-high", "6kHz", "--step", "2mm", "--primary", "1",
                 "--no-plots", "--json", "--out", str(tmp_path / "m.npz")]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["unit"] == "m/s/V" and summary["modes"] >= 5


def test_the_survey_says_each_step_with_what_it_expects(tmp_path, capsys):
    """Not on a terminal: one line per step (each sweep, the poles, the shapes), the sweeps after
    the first with the time they expect."""
    from modalctl.cli import main

    assert main(["identify", "--scene", "thesis-al-cc", "--f-high", "6kHz", "--step", "2mm", "--no-plots", "--json",
                 "--out", str(tmp_path / "m.npz")]) == 0
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("modalctl identify: ")]
    assert lines[0].startswith("modalctl identify: the survey: 100 to 6000 Hz")
    sweeps = [line for line in lines if "FRFs of actuator" in line]
    assert len(sweeps) >= 9 and "about" not in sweeps[0] and all(" s" in line and "about" in line
                                                                   for line in sweeps[1:])
    assert any("poles on" in line for line in lines) and "shapes of" in lines[-1]
    assert "\r" not in "".join(lines)


@pytest.mark.parametrize("tol", [1e-4, 0.05])
def test_one_channel_truncation_from_the_waveform_s_bounds_is_the_plant_s(tol):
    """The simulator's modes kept for a drive on one channel (the waveform's bounds, scaled by the
    channel's gains) are those :func:`truncation` keeps, its dropped bound the same; two channels
    go to it."""
    from modalctl.hil.plant import truncation

    sweep = Sweep.design(100, 20e3, 8.0)
    device = SimDevice(load_scene("thesis-al-cc"), Perturbation(), tol=tol)
    device.configure(sweep.sample_rate)
    channels = device.capabilities.channels
    dropped_any = False
    for drive in [*np.eye(channels), np.r_[1.0, 0.5, np.zeros(channels - 2)]]:
        u = drive[:, None] * sweep.waveform()
        kept, _, dropped = truncation(device.truth, u, sweep.sample_rate, tol)
        ours, our_dropped = device._truncation(u)
        assert np.array_equal(ours, kept) and our_dropped == pytest.approx(dropped, rel=1e-9, abs=1e-300)
        dropped_any |= kept.size < device.truth.n_modes
    assert dropped_any == (tol > 1e-3)
