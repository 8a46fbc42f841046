"""The simulated vibrometer (modalctl.hil.vibrometer): the field from the modes, and its noise's
statistics and bookkeeping (white, Gaussian, the same record however it is asked for)."""

import numpy as np
import pytest

from modalctl.hil.scenario import Perturbation
from modalctl.hil.sim_device import SimDevice
from modalctl.hil.vibrometer import NOISE_BLOCK, scan_field, scan_noise
from modalctl.model.scenes import load_scene


@pytest.fixture(scope="module")
def record():
    """21 modes on 2000 points, their velocities at 3000 instants spread over 12 blocks of samples."""
    rng = np.random.default_rng(11)
    shapes = rng.standard_normal((21, 2000))
    samples = np.sort(rng.choice(12 * NOISE_BLOCK, 3000, replace=False))
    return shapes, rng.standard_normal((21, samples.size)) * 1e-3, samples


def test_the_field_is_the_shapes_times_the_modal_velocities_in_float32(record):
    shapes, velocity, samples = record
    field = scan_field(shapes, velocity, samples)
    exact = shapes.T @ velocity
    assert field.dtype == np.float32 and field.shape == exact.shape
    assert np.max(np.abs(field - exact)) < 1e-6 * np.max(np.abs(exact))
    some = scan_field(shapes, velocity[:, :5], samples[:5], [7, 3, 1999])
    assert np.max(np.abs(some - exact[[7, 3, 1999], :5])) < 1e-6 * np.max(np.abs(exact))


def test_the_noise_is_white_gaussian_and_of_its_standard_deviation(record):
    """6 million draws: mean, variance, kurtosis and tails of a normal law; no correlation between
    neighbouring points, neighbouring samples, nor two shots."""
    shapes, _, samples = record
    sigma = 2e-4
    noise = scan_noise((5, 1), samples, shapes.shape[1], sigma).astype(float) / sigma
    n = noise.size
    assert noise.dtype == float and noise.shape == (shapes.shape[1], samples.size)
    assert abs(noise.mean()) < 5 / np.sqrt(n) and abs(noise.std() - 1) < 5 * np.sqrt(0.5 / n)
    assert abs(np.mean(noise ** 4) - 3) < 5 * np.sqrt(96 / n)
    for k, tail in ((1, 0.3173), (2, 0.0455), (3, 0.0027)):
        assert abs(np.mean(np.abs(noise) > k) - tail) < 5 * np.sqrt(tail / n)
    bound = 5 / np.sqrt(n)
    assert abs(np.mean(noise[1:] * noise[:-1])) < bound and abs(np.mean(noise[:, 1:] * noise[:, :-1])) < bound
    other = scan_noise((5, 2), samples, shapes.shape[1], sigma).astype(float) / sigma
    assert abs(np.mean(noise * other)) < bound


def test_a_scan_reads_one_record_however_it_is_asked_for(record):
    """Instants in two requests, points one at a time or in any order: the same noise as one scan of
    everything, to the bit (the host batches as its link allows), and the same field to float32's
    rounding (BLAS sums in an order of its own for each size); another shot, other noise."""
    shapes, velocity, samples = record
    points = shapes.shape[1]
    whole = scan_noise((2, 7), samples, points, 1e-4)
    half = samples.size // 2
    assert np.array_equal(np.hstack([scan_noise((2, 7), samples[s], points, 1e-4)
                                     for s in (slice(None, half), slice(half, None))]), whole)
    rows, picked = [1500, 3, 3, 42], [2999, 0, 1234]
    assert np.array_equal(scan_noise((2, 7), samples, points, 1e-4, rows), whole[rows])
    assert np.array_equal(scan_noise((2, 7), samples[picked], points, 1e-4, 42), whole[[42]][:, picked])
    assert np.mean(scan_noise((2, 8), samples, points, 1e-4) == whole) < 1e-3
    field = scan_field(shapes, velocity, samples, None, 1e-4, (2, 7))
    some = scan_field(shapes, velocity[:, picked], samples[picked], rows, 1e-4, (2, 7))
    assert np.max(np.abs(some - field[rows][:, picked])) < 1e-6 * np.max(np.abs(field))
    with pytest.raises(ValueError, match="sample indices"):
        scan_noise((0,), np.array([-1]), 3, 1.0)


def test_the_simulators_scan_adds_its_noise_to_the_modes_field():
    """SimDevice: the scan at 30 dB against the modes' own field, its noise's standard deviation the
    shot's peak over 10^(30/20), and the same instants scanned twice read the same."""
    model = load_scene("thesis-al-cc", 105).select(np.arange(5))
    fs, n = 200e3, 2000
    u = np.zeros((8, n))
    u[0] = np.sin(model.omega[1] * np.arange(n) / fs)
    device = SimDevice(model, Perturbation(snr_db=30.0))
    device.configure(fs)
    device.activate()
    device.upload(u)
    device.trigger()
    kept, velocity = device.modal_truth()
    truth = model.shapes[kept].T @ velocity
    times = np.arange(n) / fs
    field = device.scan(times)
    assert field.dtype == np.float32
    sigma = np.max(np.abs(truth)) / 10 ** 1.5
    assert np.std(field - truth) == pytest.approx(sigma, rel=0.05)
    assert np.array_equal(device.scan(times[::7], [4, 60]), field[[4, 60]][:, ::7])
