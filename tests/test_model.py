"""Validation with clear errors, subsets, and files without pickle."""

import json
from dataclasses import replace

import numpy as np
import pytest

from modalctl.model.files import read_shapes_csv, read_uff55
from modalctl.model.modes import Grid, ModalModel, ModelError


@pytest.fixture
def model(al_beam):
    return al_beam.modal_model(6, n_points=201, patches=[], sensors=[0.01])


@pytest.mark.parametrize("change, field", [
    (dict(frequencies=[100, np.nan, 300, 400, 500, 600]), "frequencies"),
    (dict(frequencies=[100, 0, 300, 400, 500, 600]), "frequencies"),
    (dict(damping=[0.01, 0.01, 1.2, 0.01, 0.01, 0.01]), "damping"),
    (dict(damping=[0.01, 0.01, 0.0, 0.01, 0.01, 0.01]), "damping"),
    (dict(shapes=np.zeros((6, 10))), "shapes"),
    (dict(actuator_gains=np.zeros((5, 2))), "actuator_gains"),
    (dict(labels=[1, 1, 2, 3, 4, 5]), "labels"),
    (dict(meta={"x": object()}), "meta"),
])
def test_bad_input_names_field(model, change, field):
    with pytest.raises(ModelError) as info:
        replace(model, **change)
    assert field in str(info.value)


def test_errors_give_the_value(model):
    with pytest.raises(ModelError, match=r"-5\.0"):
        replace(model, frequencies=[100, -5.0, 300, 400, 500, 600])


def test_bad_grids():
    with pytest.raises(ModelError, match="empty grid"):
        Grid(np.zeros((0, 1)), np.zeros(0))
    with pytest.raises(ModelError, match="grid.mass"):
        Grid(np.zeros((3, 1)), np.ones(4))
    with pytest.raises(ModelError, match="grid.points"):
        Grid(np.array([[0.0], [np.nan]]), np.ones(2))


def test_select_keeps_modes_consistent(model):
    sub = model.select([4, 1])
    assert sub.labels.tolist() == [5, 2]
    assert sub.shapes == pytest.approx(model.shapes[[4, 1]])
    assert sub.sensor_gains == pytest.approx(model.sensor_gains[[4, 1]])
    assert model.index_of([5, 2]).tolist() == [4, 1]
    with pytest.raises(ModelError, match="out of range"):
        model.select([9])


def test_save_load_roundtrip_without_pickle(model, tmp_path):
    path = model.save(tmp_path / "beam")
    assert path.suffix == ".npz"
    with np.load(path, allow_pickle=False) as data:  # readable without pickle
        header = json.loads(str(data["meta_json"]))
    assert header["format"] == "modalctl.ModalModel"
    back = ModalModel.load(path)
    for name in ("frequencies", "damping", "shapes", "actuator_gains", "sensor_gains", "labels", "rigid_shapes"):
        assert np.array_equal(getattr(back, name), getattr(model, name)), name
    assert np.array_equal(back.grid.mass, model.grid.mass)
    assert back.meta == model.meta


def test_load_errors(tmp_path):
    with pytest.raises(ModelError, match="no such file"):
        ModalModel.load(tmp_path / "missing.npz")
    bad = tmp_path / "bad.npz"
    np.savez(bad, x=np.ones(3))
    with pytest.raises(ModelError, match="meta_json"):
        ModalModel.load(bad)


def _rewritten(path, out, change):
    """``path``'s arrays with ``change`` (name -> array, or None to drop it) written to ``out``."""
    with np.load(path, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    for name, value in change.items():
        arrays.pop(name) if value is None else arrays.__setitem__(name, value)
    np.savez(out, **arrays)
    return out


def test_damaged_model_files_are_refused_with_a_reason(model, tmp_path):
    """Issue 26's files, each a traceback (BadZipFile, TypeError) or a nonsense run before."""
    good = model.save(tmp_path / "good")
    raw = good.read_bytes()
    cases = {"truncated": raw[: len(raw) // 2], "empty": b"", "corrupted": raw[:40] + bytes(200) + raw[240:]}
    for name, content in cases.items():
        (tmp_path / f"{name}.npz").write_bytes(content)
        with pytest.raises(ModelError, match="not a modalctl .npz model|model file"):
            ModalModel.load(tmp_path / f"{name}.npz")
    extra = _rewritten(good, tmp_path / "extra.npz", {"secret": np.ones(2)})
    with pytest.raises(ModelError, match=r"unknown entries \['secret'\]"):
        ModalModel.load(extra)
    missing = _rewritten(good, tmp_path / "missing.npz", {"shapes": None})
    with pytest.raises(ModelError, match=r"missing entries \['shapes'\]"):
        ModalModel.load(missing)
    scaled = _rewritten(good, tmp_path / "scaled.npz", {"shapes": 5.5 * model.shapes})
    with pytest.raises(ModelError, match="mass-normalized"):
        ModalModel.load(scaled)
    not_json = _rewritten(good, tmp_path / "notjson.npz", {"meta_json": np.array("{not json")})
    with pytest.raises(ModelError, match="meta_json is not JSON"):
        ModalModel.load(not_json)


def test_a_model_file_declaring_terabytes_is_refused_unread(model, tmp_path):
    """An .npy header may claim any shape: the loader reads the headers first and refuses the file."""
    import io
    import zipfile

    good = model.save(tmp_path / "good")
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": (2**41,)})
    huge = tmp_path / "huge.npz"
    with zipfile.ZipFile(good) as source, zipfile.ZipFile(huge, "w") as target:
        for info in source.infolist():
            target.writestr(info, header.getvalue() + bytes(64) if info.filename == "shapes.npy"
                            else source.read(info))
    with pytest.raises(ModelError, match="declares 17592186044416 bytes and holds 64: truncated"):
        ModalModel.load(huge)


def test_csv_shapes(tmp_path, al_beam):
    grid = al_beam.grid(101)
    shapes = al_beam.shapes(grid.x, 3)
    path = tmp_path / "modes.csv"
    lines = ["# identified modes", "x,mode1,mode2,mode3"]
    lines += [",".join(f"{v:.17g}" for v in (x, *col)) for x, col in zip(grid.x, shapes.T)]
    path.write_text("\n".join(lines))
    points, read, names = read_shapes_csv(path)
    assert names == ["mode1", "mode2", "mode3"]
    assert points[:, 0] == pytest.approx(grid.x)
    assert read == pytest.approx(shapes)
    with pytest.raises(ModelError, match="no such file"):
        read_shapes_csv(tmp_path / "none.csv")
    path.write_text("x,mode1\n0.1,abc\n")
    with pytest.raises(ModelError, match="csv"):
        read_shapes_csv(path)
    path.write_bytes(bytes(range(256)) * 8)  # issue 26: a binary file ended in UnicodeDecodeError
    with pytest.raises(ModelError, match="not a text table"):
        read_shapes_csv(path)


def test_uff55_roundtrip(tmp_path, al_beam):
    pyuff = pytest.importorskip("pyuff")
    x = np.linspace(-0.05, 0.05, 11)
    shapes = al_beam.shapes(x, 3)
    path = tmp_path / "modes.uff"
    uff = pyuff.UFF(str(path))
    for k, (f, z) in enumerate([(368.0, 0.0118), (963.0, 0.0228), (2253.0, 0.0286)]):
        uff.write_sets(pyuff.prepare_55(
            model_type=1, id1="modalctl test", id2="", id3="", id4="", id5="", analysis_type=2, data_ch=2,
            spec_data_type=8, data_type=2, n_data_per_node=3, r1=np.zeros(11), r2=np.zeros(11), r3=shapes[k],
            node_nums=np.arange(1, 12), load_case=1, mode_n=k + 1, modal_m=0, freq=f, modal_damp_vis=z,
            modal_damp_his=0.0), mode="add" if k else "overwrite")
    data = read_uff55(path)
    assert data["frequencies"] == pytest.approx([368.0, 963.0, 2253.0])
    assert data["damping"] == pytest.approx([0.0118, 0.0228, 0.0286])
    assert data["shapes"] == pytest.approx(shapes, rel=1e-5, abs=1e-6 * np.abs(shapes).max())
    assert data["node_nums"].tolist() == list(range(1, 12))
