"""A run's field on file: read back as measured (within its step), small where the field is modal."""

import numpy as np
import pytest

from modalctl.model.modes import ModelError
from modalctl.model.records import RESOLUTION, read_field_record, write_field_record
from modalctl.model.scenes import load_scene


def _kept(back, field) -> bool:
    """Every sample within half a step, plus float32's rounding of the sums at the peak (2^-20 of it)."""
    return bool(np.abs(back.field - field).max() <= 0.5 * back.step + 2.0 ** -20 * np.abs(field).max())


def _modal_field(model, nt: int = 400, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A free decay of every mode from random velocities: what a structure's field is, independent of
    the planner and the simulator."""
    rng = np.random.default_rng(seed)
    t = np.arange(nt) / (16 * model.frequencies.max())
    velocity = rng.standard_normal(model.n_modes)[:, None] * np.exp(-model.damping[:, None] * model.omega[:, None] * t) \
        * np.cos(model.omega[:, None] * t + rng.uniform(0, 2 * np.pi, model.n_modes)[:, None])
    return t, (model.shapes.T @ velocity).astype(np.float32)


@pytest.fixture(scope="module")
def plate():
    return load_scene("plate-glass")


def test_a_modal_field_reads_back_within_its_step_and_compresses_tenfold(plate, tmp_path):
    t, field = _modal_field(plate)
    path = write_field_record(tmp_path / "f.npz", t, plate.grid.points, field)
    back = read_field_record(path)
    peak = np.abs(field).max()
    assert back.step == pytest.approx(peak * RESOLUTION)  # nothing left by the modes: the finest step
    assert _kept(back, field)
    assert back.rank <= plate.n_modes
    np.testing.assert_array_equal(back.times, t)
    np.testing.assert_array_equal(back.points, plate.grid.points)
    assert path.stat().st_size * 10 < field.nbytes, path.stat().st_size


def test_noise_is_kept_as_measured(plate, tmp_path):
    t, field = _modal_field(plate, seed=1)
    noisy = field + np.float32(0.01 * np.abs(field).max()) * np.random.default_rng(2).standard_normal(field.shape,
                                                                                                   np.float32)
    back = read_field_record(write_field_record(tmp_path / "f.npz", t, plate.grid.points, noisy))
    assert _kept(back, noisy)
    residual = back.field - field  # the noise, as measured
    assert np.std(residual) == pytest.approx(0.01 * np.abs(field).max(), rel=0.02)
    assert np.std(back.field - noisy) < 0.05 * np.std(residual)  # the rounding: 1/28 of the noise
    assert back.step <= 2.0 ** -10 * np.abs(noisy).max()


def test_a_sample_beyond_sixteen_bits_of_the_residual_is_kept_too(tmp_path):
    rng = np.random.default_rng(3)
    field = rng.standard_normal((300, 200)).astype(np.float32)  # full rank: the residual carries a lot
    field[17, 33] = 50.0  # a spike the low-rank part misses by more than 2^15 steps
    back = read_field_record(write_field_record(tmp_path / "f.npz", np.arange(200) * 1e-5, np.zeros((300, 1)),
                                                field, extra={"note": np.arange(3)}))
    assert _kept(back, field)
    np.testing.assert_array_equal(back.extra["note"], np.arange(3))


def test_bad_fields_and_files_are_refused(tmp_path):
    with pytest.raises(ModelError, match="NaN"):
        write_field_record(tmp_path / "f.npz", [0.0, 1.0], np.zeros((2, 1)), np.array([[0.0, np.nan], [1, 2]]))
    with pytest.raises(ModelError, match="does not match"):
        write_field_record(tmp_path / "f.npz", [0.0], np.zeros((2, 1)), np.zeros((2, 3)))
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(ModelError, match="cannot read"):
        read_field_record(tmp_path / "junk.npz")
    np.savez(tmp_path / "other.npz", a=np.arange(3))
    with pytest.raises(ModelError, match="cannot read|not a field record"):
        read_field_record(tmp_path / "other.npz")
