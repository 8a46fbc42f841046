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
    with pytest.raises(ValueError, match="NaN"):  # the field modalctl made: a bug, not bad input (issue 39)
        write_field_record(tmp_path / "f.npz", [0.0, 1.0], np.zeros((2, 1)), np.array([[0.0, np.nan], [1, 2]]))
    with pytest.raises(ValueError, match="does not match"):
        write_field_record(tmp_path / "f.npz", [0.0], np.zeros((2, 1)), np.zeros((2, 3)))
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(ModelError, match="cannot read"):
        read_field_record(tmp_path / "junk.npz")
    np.savez(tmp_path / "other.npz", a=np.arange(3))
    with pytest.raises(ModelError, match="cannot read|not a field record"):
        read_field_record(tmp_path / "other.npz")


def _simulated_scan(snr_db: float | None = 30.0):
    """A simulated shot on five modes and the times to scan (SimDevice, its noise ``snr_db`` below its peak)."""
    from modalctl.hil.scenario import Perturbation
    from modalctl.hil.sim_device import SimDevice

    model = load_scene("thesis-al-cc", 105).select(np.arange(5))
    fs, n = 200e3, 3000
    u = np.zeros((8, n))
    u[0] = np.sin(model.omega[1] * np.arange(n) / fs)
    device = SimDevice(model, Perturbation(snr_db=snr_db, seed=4))
    device.configure(fs)
    device.activate()
    device.upload(u)
    device.trigger()
    times = np.arange(0, n, 2) / fs
    return model, device, times


def test_a_simulated_vibrometers_noise_is_stored_as_its_key_and_read_back_as_measured(tmp_path):
    """The scan's noise described by the device (its generator's key, sigma, samples and rows) is
    taken away before the field is split and added back on reading: the field read back is the
    device's own scan within half the step, the step the noise-free field's (2^-16 of the peak),
    and the file as small as a noise-free field's, where the noise as samples takes 5 bits each."""
    model, device, times = _simulated_scan()
    field, noise = device.scan(times), device.scan_noise_stream(times)
    assert noise is not None and noise.shape == field.shape and noise.key[0] == 4
    described = write_field_record(tmp_path / "key.npz", times, model.grid.points, field, noise=noise,
                                   basis=model.shapes.T)
    back = read_field_record(described)
    assert _kept(back, field)
    assert back.step == pytest.approx(np.abs(field).max() * RESOLUTION, rel=1e-6)
    assert back.noise is not None and back.noise.sigma == noise.sigma and back.rank <= 5
    np.testing.assert_array_equal(back.noise.samples, noise.samples)
    as_samples = write_field_record(tmp_path / "samples.npz", times, model.grid.points, field, basis=model.shapes.T)
    kept = read_field_record(as_samples)
    assert _kept(kept, field) and kept.noise is None and kept.step > 30 * back.step
    assert described.stat().st_size * 5 < as_samples.stat().st_size
    assert as_samples.stat().st_size > field.size * 4 / 8  # at least 4 bits a sample of noise
    some = device.scan(times[::5], [3, 40, 7])  # a scan of some points, its own description
    back = read_field_record(write_field_record(tmp_path / "some.npz", times[::5], model.grid.points[[3, 40, 7]],
                                                some, noise=device.scan_noise_stream(times[::5], [3, 40, 7])))
    assert _kept(back, some)


def test_a_noise_free_simulation_and_a_real_vibrometer_describe_no_noise():
    _, device, times = _simulated_scan(None)
    assert device.scan_noise_stream(times) is None

    from modalctl.io.device import Device

    class Bench(Device):  # a device that says nothing of its noise: the contract's default
        configure = upload = trigger = lambda self, *a, **k: None

    assert Bench("bench://").scan_noise_stream(times) is None


def _with_header(path, other, change) -> None:
    """Copy the record ``path`` to ``other`` with ``change(header)`` applied to its header."""
    import json
    import zipfile

    header = json.loads(str(np.load(path)["header_json"]))
    header = change(header) or header
    with zipfile.ZipFile(path) as source, zipfile.ZipFile(other, "w") as target:
        for member in source.namelist():
            if member == "header_json.npy":
                with target.open(member, "w") as out:
                    np.lib.format.write_array(out, np.array(json.dumps(header)))
            else:
                target.writestr(member, source.read(member))


def test_a_noise_generator_this_modalctl_does_not_have_is_refused(tmp_path):
    """A record whose noise came from another generator's version cannot give back the field: refused."""
    model, device, times = _simulated_scan()
    path = write_field_record(tmp_path / "f.npz", times, model.grid.points, device.scan(times),
                              noise=device.scan_noise_stream(times))
    other = tmp_path / "other.npz"
    _with_header(path, other, lambda header: header["noise"].update(version=99))
    with pytest.raises(ModelError, match="version 99.*cannot give back"):
        read_field_record(other)
    with pytest.raises(ValueError, match="generator"):  # writing what modalctl made: a bug, not bad input
        from dataclasses import replace

        write_field_record(tmp_path / "g.npz", times, model.grid.points, device.scan(times),
                           noise=replace(device.scan_noise_stream(times), version=99))


def test_a_header_out_of_shape_is_a_model_error(tmp_path):
    """A noise entry that is not a description, a header that is not an object, a step missing, a
    residual of another shape: each a ModelError, never an AttributeError or KeyError."""
    model, device, times = _simulated_scan()
    path = write_field_record(tmp_path / "f.npz", times, model.grid.points, device.scan(times),
                              noise=device.scan_noise_stream(times))
    changes = {"noise": lambda header: header.update(noise="key 4"),
               "noise list": lambda header: header.update(noise=[4, 1e-3]),
               "noise key": lambda header: header["noise"].update(key=4),
               "step": lambda header: header.pop("step_m_per_s"),
               "list": lambda header: [header]}
    for name, change in changes.items():
        _with_header(path, tmp_path / f"{name}.npz", change)
        with pytest.raises(ModelError, match="noise|cannot read|not a field record"):
            read_field_record(tmp_path / f"{name}.npz")


def test_a_field_with_modes_the_basis_lacks_is_kept_at_the_finest_step(plate, tmp_path):
    """The model's basis lacking a mode the structure has (another truth scene, a real structure):
    what the basis leaves is that mode, not noise, so the range finder adds it and the field is
    stored as a noise-free one: the finest step, read back within it, the file small."""
    t, field = _modal_field(plate, seed=5)
    lacking = plate.select(np.delete(np.arange(plate.n_modes), 2))  # the third mode missing
    path = write_field_record(tmp_path / "f.npz", t, plate.grid.points, field, basis=lacking.shapes.T)
    back = read_field_record(path)
    peak = np.abs(field).max()
    assert back.step == pytest.approx(peak * RESOLUTION)
    assert _kept(back, field)
    assert back.rank <= plate.n_modes
    assert path.stat().st_size * 10 < field.nbytes, path.stat().st_size
    missing = write_field_record(tmp_path / "g.npz", t, plate.grid.points, field,  # a basis of two fewer modes
                                 basis=plate.select(np.arange(2, plate.n_modes)).shapes.T)
    assert read_field_record(missing).step == pytest.approx(peak * RESOLUTION)


@pytest.mark.parametrize("shape", [(5, 0), (0, 7), (0, 0)])
def test_an_empty_field_writes_and_reads(shape, tmp_path):
    n, nt = shape
    for basis in (None, np.ones((n, 3))):
        path = write_field_record(tmp_path / "f.npz", np.arange(nt) * 1e-5, np.zeros((n, 2)),
                                  np.zeros(shape, np.float32), basis=basis)
        back = read_field_record(path)
        assert back.field.shape == shape and back.points.shape == (n, 2) and back.times.shape == (nt,)
        assert back.step > 0 and back.rank == 0


def test_a_simulators_field_is_stored_as_the_modes_it_made_and_read_back_with_its_noise(plate, tmp_path):
    """``modes``: the simulated vibrometer's field (its modes' shapes times their velocities, plus keyed
    noise, as :func:`~modalctl.hil.vibrometer.scan_field` makes it) stored without a pass over it."""
    from modalctl.hil.vibrometer import scan_field, scan_noise_stream

    rng = np.random.default_rng(5)
    samples = np.arange(0, 2400, 6)
    velocity = rng.standard_normal((plate.n_modes, samples.size)).astype(np.float32)
    sigma = 0.01 * float(np.abs(plate.shapes.T @ velocity).max())
    field = scan_field(plate.shapes, velocity, samples, sigma=sigma, key=(7, 1))
    noise = scan_noise_stream((7, 1), samples, plate.grid.n, sigma)
    t = samples / 1e5
    made = write_field_record(tmp_path / "made.npz", t, plate.grid.points, field, noise=noise,
                              basis=plate.shapes.T, modes=(plate.shapes.T, velocity))
    back = read_field_record(made)
    assert _kept(back, field) and back.step == pytest.approx(np.abs(field).max() * RESOLUTION)
    assert back.rank == plate.n_modes
    # modes that did not make the field (one velocity off) are found out and the field is stored by its passes
    off = velocity.copy()
    off[3] *= 1.01
    other = read_field_record(write_field_record(tmp_path / "off.npz", t, plate.grid.points, field, noise=noise,
                                                 basis=plate.shapes.T, modes=(plate.shapes.T, off)))
    assert _kept(other, field)
    with pytest.raises(ValueError, match="modes"):
        write_field_record(tmp_path / "bad.npz", t, plate.grid.points, field, modes=(plate.shapes.T, velocity[:, :5]))


def test_large_floating_arrays_are_stored_as_they_are_and_the_rest_deflated(tmp_path):
    """Measured floats deflate by a few per cent at a second per 32 MB: over STORED_BYTES they are stored;
    the residual's steps and the small arrays are deflated; the field reads back as written."""
    import zipfile

    from modalctl.model.records import STORED_BYTES

    rng = np.random.default_rng(2)
    n, k, nt = 700, 400, 600  # the basis: 700 x 400 float32, 1.1 MB
    basis = rng.standard_normal((n, k)).astype(np.float32)
    field = basis @ rng.standard_normal((k, nt)) + 1e-3 * rng.standard_normal((n, nt))
    times, points = np.arange(nt) / 20e3, np.c_[np.arange(n) * 1e-3, np.zeros(n)]
    path = write_field_record(tmp_path / "f.npz", times, points, field, basis=basis)
    with zipfile.ZipFile(path) as archive:
        kinds = {info.filename: info.compress_type for info in archive.infolist()}
        sizes = {info.filename: info.file_size for info in archive.infolist()}
    assert sizes["basis.npy"] > STORED_BYTES and kinds["basis.npy"] == zipfile.ZIP_STORED
    assert kinds["residual.npy"] == kinds["times.npy"] == kinds["points.npy"] == zipfile.ZIP_DEFLATED
    assert _kept(read_field_record(path), field)


def test_the_noise_drawn_on_two_threads_is_the_noise_drawn_on_one_and_on_any_subset(monkeypatch):
    from modalctl.model import noise_stream

    shot, samples = noise_stream.shot_key((3, 5)), np.arange(0, 9000, 3)  # 3000 instants: 43 points a block
    rows = np.random.default_rng(0).permutation(4000)[:3000]  # 9e6 values: made on two threads, in any order
    threaded = np.zeros((rows.size, samples.size), np.float32)
    noise_stream.add_noise(threaded, shot, rows, samples, 2e-3)
    monkeypatch.setattr(noise_stream, "THREADED_VALUES", 10**12)  # every block on this thread
    serial = np.zeros_like(threaded)
    noise_stream.add_noise(serial, shot, rows, samples, 2e-3)
    assert np.array_equal(threaded, serial)
    some = np.zeros((3, samples.size), np.float32)
    noise_stream.add_noise(some, shot, rows[[0, 700, 2999]], samples, 2e-3)
    assert np.array_equal(some, serial[[0, 700, 2999]])
    assert abs(float(serial.std()) / 2e-3 - 1) < 0.01  # the noise asked for (9 M draws)
