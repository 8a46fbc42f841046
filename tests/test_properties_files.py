"""Property-based checks of what the parsers do not declare (issue 39): hostile files (npz archives,
npy arrays, universal files), output paths and ``sweep --vary`` values. Whatever they hold, modalctl
reads them or refuses them with its own error (exit 2), never numpy's, zipfile's or pyuff's
exception, never an allocation their headers alone ask for. Derandomized: the same examples on
every run (CI's included)."""

import io
import json
import math
import os
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from modalctl.cli import main
from modalctl.cli.common import option_type
from modalctl.cli.sweep import SWEPT, _swept_values
from modalctl.model import files
from modalctl.model.modes import MODEL_ARRAYS, ModalModel, ModelError
from modalctl.model.scenes import load_scene
from modalctl.model.shape import ParamError
from modalctl.outdir import OutDirError, atomic, check_writable

SETTINGS = dict(deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
DTYPES = ["<f8", "<f4", "<i8", "|u1", "|b1", "<c16", "<U4", "|S3", "|O", "<M8[s]", "[('a', '<f8')]", "nonsense"]


@pytest.fixture(scope="module")
def model_file(tmp_path_factory) -> Path:
    return load_scene("thesis-al-cc", 61).save(tmp_path_factory.mktemp("model") / "beam.npz")


@st.composite
def npy_bytes(draw) -> bytes:
    """An ``.npy`` stream: a header of any dtype and shape (terabytes declared in a few bytes
    included), then data of any length."""
    shape = tuple(draw(st.lists(st.one_of(st.integers(0, 8), st.integers(2**20, 2**45)), max_size=3)))
    descr = draw(st.sampled_from(DTYPES))
    header = repr({"descr": descr, "fortran_order": draw(st.booleans()), "shape": shape}).encode()
    if draw(st.booleans()):  # a header numpy writes
        header = header + b" " * (-(len(header) + 11) % 64) + b"\n"
    version = draw(st.sampled_from([b"\x01\x00", b"\x02\x00", b"\x03\x00", b"\x09\x09"]))
    length = len(header).to_bytes(2 if version == b"\x01\x00" else 4, "little")
    count = int(np.prod(shape, dtype=object)) if shape else 1
    data = draw(st.one_of(st.binary(max_size=64), st.just(bytes(16 * count) if count <= 8 else b"")))
    return b"\x93NUMPY" + version + length + header + data


def _member(draw, name: str, arrays: dict) -> bytes:
    """One member of an archive: the model's own array (perhaps changed), a hostile .npy, or bytes."""
    kind = draw(st.sampled_from(["own", "npy", "bytes", "transposed", "float-labels"]))
    if kind == "npy":
        return draw(npy_bytes())
    if kind == "bytes":
        return draw(st.binary(max_size=200))
    value = arrays.get(name[:-4], np.arange(3.0))
    if kind == "transposed":
        value = np.asarray(value).T.copy()
    elif kind == "float-labels" and np.asarray(value).dtype.kind in "biuf":
        value = np.asarray(value, float).copy()
        if value.size:
            value.flat[draw(st.integers(0, value.size - 1))] = draw(st.sampled_from([np.nan, np.inf, 0.5, -1.0, 1e300]))
    out = io.BytesIO()
    np.save(out, value)
    return out.getvalue()


_json = st.recursive(st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
                     lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=6), inner, max_size=3),
                     max_leaves=8)


@st.composite
def hostile_npz(draw, model_file: Path) -> bytes:
    """An archive made of a model file's members, each kept, changed or replaced; meta of any JSON;
    members stored, deflated or compressed as numpy never does."""
    with np.load(model_file) as data:
        arrays = {key: data[key] for key in data.files}
    header = json.loads(str(arrays["meta_json"]))
    names = sorted({*draw(st.lists(st.sampled_from(sorted(MODEL_ARRAYS | {"meta_json", "surprise"})), max_size=12)),
                    *(["points", "mass", "frequencies", "damping", "shapes"] if draw(st.booleans()) else [])})
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as archive:
        for name in names:
            compress = draw(st.sampled_from([zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED, zipfile.ZIP_BZIP2]))
            if name == "meta_json" and draw(st.booleans()):
                meta = draw(st.one_of(_json, st.just({**header, "meta": draw(_json)})))
                buffer = io.BytesIO()
                np.save(buffer, np.array(json.dumps(meta)))
                body = buffer.getvalue()
            else:
                body = _member(draw, f"{name}.npy", arrays)
            archive.writestr(f"{name}.npy", body, compress_type=compress)
    raw = out.getvalue()
    if draw(st.booleans()):  # then cut or flipped
        at = draw(st.integers(0, max(0, len(raw) - 1)))
        raw = raw[:at] if draw(st.booleans()) else raw[:at] + bytes([raw[at] ^ 0x55]) + raw[at + 1:]
    return raw


@settings(max_examples=150, **SETTINGS)
@given(data=st.data())
def test_a_hostile_npz_loads_into_a_sound_model_or_is_refused(model_file, tmp_path, data):
    path = tmp_path / "hostile.npz"
    path.write_bytes(data.draw(hostile_npz(model_file)))
    try:
        model = ModalModel.load(path)
    except ModelError:
        return
    assert isinstance(model.meta, dict)
    assert np.all(np.isfinite(model.frequencies)) and np.all(model.frequencies > 0)
    assert len(np.unique(model.grid.points, axis=0)) == model.grid.n
    assert model.labels.dtype.kind == "i" and len(set(model.labels.tolist())) == model.n_modes


@settings(max_examples=150, **SETTINGS)
@given(raw=npy_bytes())
def test_a_hostile_npy_is_read_within_its_file_or_refused(tmp_path, raw):
    path = tmp_path / "values.npy"
    path.write_bytes(raw)
    try:
        array = files.read_npy(path)
    except ModelError:
        return
    assert array.dtype.kind in "biuf" and array.nbytes <= len(raw)


# -- universal files ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def uff_text(tmp_path_factory) -> bytes:
    pytest.importorskip("pyuff")
    from test_uff import grid_points, mobility, write

    points = grid_points(3, 3)
    return write(tmp_path_factory.mktemp("uff") / "plate.uff", points, mobility(points)).read_bytes()


@settings(max_examples=60, **SETTINGS)
@given(data=st.data())
def test_a_damaged_universal_file_is_read_or_refused_with_modalctls_error(uff_text, tmp_path, data):
    from modalctl.identify.frf import read_uff58

    lines = uff_text.splitlines(keepends=True)
    damage = data.draw(st.sampled_from(["cut", "line", "junk", "swap", "drop"]))
    at = data.draw(st.integers(0, len(lines) - 1))
    if damage == "cut":
        lines = lines[:at] + [lines[at][:data.draw(st.integers(0, len(lines[at])))]]
    elif damage == "line":
        lines[at] = data.draw(st.sampled_from([b"    -1\n", b"   58\n", b"\n", b"nan nan nan\n", b"    15\n",
                                               b"1e999 -1e999\n", b" " * 80 + b"\n"]))
    elif damage == "junk":
        lines[at] = data.draw(st.binary(min_size=1, max_size=40)) + b"\n"
    elif damage == "swap":
        other = data.draw(st.integers(0, len(lines) - 1))
        lines[at], lines[other] = lines[other], lines[at]
    else:
        del lines[at:at + data.draw(st.integers(1, 20))]
    path = tmp_path / "damaged.uff"
    path.write_bytes(b"".join(lines))
    try:
        frf = read_uff58(path)
    except ModelError:
        return
    assert np.all(np.isfinite(frf.frequencies)) and np.all(np.isfinite(frf.values))


# -- output paths --------------------------------------------------------------------------------------
STARTS = ["root", "file", "folder", "link", "/proc", "/sys", "/dev", "/dev/null", "/proc/self"]
NAMES = st.one_of(st.text(st.characters(blacklist_categories=["Cs"], blacklist_characters="/\x00"), min_size=1,
                          max_size=12), st.sampled_from(["..", ".", "model.npz", "file", "x" * 300]))


@st.composite
def output_path(draw) -> tuple[str, list[str], bool]:
    """(where it starts, the names after it, whether a folder is asked): the kernel's and the
    devices' places, paths through a file, existing files and folders, a link, names of any
    characters; :func:`_placed` lays it under a fresh folder."""
    return draw(st.sampled_from(STARTS)), draw(st.lists(NAMES, max_size=3)), draw(st.booleans())


def _placed(drawn, tmp_path: Path) -> tuple[Path, bool]:
    start, parts, folder = drawn
    if start.startswith("/"):  # '/proc/..' is '/', which root may write: not a place for a test to try
        parts = [part for part in parts if part != ".."]
    root = Path(tempfile.mkdtemp(dir=tmp_path)) / "a" / "b" / "c"  # three '..' stay in the test's folder
    root.mkdir(parents=True)
    (root / "file").write_text("x")
    (root / "folder").mkdir()
    (root / "link").symlink_to(root / "file")
    return (root if start == "root" else root / start if not start.startswith("/") else Path(start)).joinpath(
        *parts), folder


@settings(max_examples=150, **SETTINGS)
@given(drawn=output_path())
def test_an_output_path_is_refused_or_takes_a_file_atomically(tmp_path, drawn):
    path, folder = _placed(drawn, tmp_path)
    try:
        check_writable(path, folder)
    except OutDirError:
        return
    resolved = Path(os.path.realpath(path))
    assert resolved.is_relative_to(os.path.realpath(tmp_path)), f"{path} accepted outside the test's folder"
    target = path / "metrics.json" if folder else path
    target.parent.mkdir(parents=True, exist_ok=True)
    with atomic(target) as temporary:
        temporary.write_text("{}")
    assert target.read_text() == "{}"


@settings(max_examples=20, **SETTINGS)
@given(drawn=output_path())
def test_decompose_saves_its_model_or_refuses_the_path_with_exit_2(tmp_path, capsys, drawn):
    path, _ = _placed(drawn, tmp_path)
    try:
        code = main(["decompose", "--scene", "thesis-al-cc", "--points", "61", "--shape", "sinc", "--json",
                     "--save-model", str(path)])
    except SystemExit as exit_:
        code = exit_.code
    said = capsys.readouterr()
    assert code in (0, 2), said.err
    assert "Traceback" not in said.err
    if code == 0:
        assert ModalModel.load(json.loads(said.out)["model_file"]).n_modes > 0


# -- sweep --vary values -------------------------------------------------------------------------------
VALUES = st.one_of(st.floats().map(repr), st.sampled_from(["nan", "inf", "-inf", "1e400", "", " ", "1,", "%", "1e9%",
                                                           "-0", "0x10", "1_000", "2ms", "1kHz", "3Ns/m", "1%"]),
                   st.integers(-10**12, 10**12).map(str), st.text("0123456789.e-+%msN/ ", max_size=6))


@settings(max_examples=300, **SETTINGS)
@given(name=st.sampled_from(sorted(SWEPT)), values=st.lists(VALUES, min_size=1, max_size=4))
def test_a_swept_value_is_one_run_accepts_or_refused(name, values):
    bounds = option_type("run", f"--{name}").bounds
    try:
        field, read = _swept_values(name, ",".join(values))
    except ParamError:
        return
    assert field == SWEPT[name]
    assert all(math.isfinite(v) and bounds.holds(v) for v in read), (name, values, read)


@settings(max_examples=40, **SETTINGS)
@given(name=st.sampled_from(sorted(SWEPT)), value=st.sampled_from(["nan", "inf", "-inf", "1e400", "-1", "1e12"]))
def test_sweep_refuses_a_value_run_refuses_with_exit_2_before_any_case(tmp_path, capsys, name, value):
    try:
        run = main(["run", "--scene", "thesis-al-cc", "--points", "61", "--shape", "sinc", "--focus-time", "25ms",
                    "--quiet", "--no-plots", f"--{name}", value, "--out", str(tmp_path / "run")])
    except SystemExit as exit_:
        run = exit_.code
    if run != 2:  # a value run takes (1e12 as a seed is refused; -1 as a drift is -100%, refused too)
        return
    assert main(["sweep", "--vary", f"{name}={value}", "--quiet", "--out", str(tmp_path / "sweep")]) == 2
    assert not (tmp_path / "sweep" / "sweep.json").exists()


# -- CSV tables ----------------------------------------------------------------------------------------
CELLS = st.one_of(st.floats().map(repr), st.sampled_from(["", " ", "x", "y", "nan", "1e400", "#", "\"", "1;2", "\x00"]),
                  st.text(max_size=5))


@settings(max_examples=150, **SETTINGS)
@given(rows=st.lists(st.lists(CELLS, min_size=0, max_size=5), max_size=6), header=st.booleans(),
       raw=st.binary(max_size=40))
def test_a_hostile_csv_is_read_as_finite_shapes_or_refused(tmp_path, rows, header, raw):
    path = tmp_path / "shapes.csv"
    text = "\n".join(",".join(row) for row in ([["x", "mode1"]] if header else []) + rows)
    path.write_bytes(text.encode("utf-8", "surrogatepass") + raw)
    try:
        points, shapes, names = files.read_shapes_csv(path)
    except ModelError:
        return
    assert np.all(np.isfinite(points)) and np.all(np.isfinite(shapes)) and shapes.shape[0] == len(names)


@settings(max_examples=60, **SETTINGS)
@given(rows=st.lists(CELLS, max_size=70), raw=st.binary(max_size=20))
def test_a_hostile_csv_of_values_gives_a_target_or_exit_2(tmp_path, capsys, rows, raw):
    path = tmp_path / "values.csv"
    path.write_bytes("\n".join(rows).encode("utf-8", "surrogatepass") + raw)
    code = main(["decompose", "--scene", "thesis-al-cc", "--points", "61", "--shape", "array", "--param",
                 f"values={path}"])
    assert code in (0, 1, 2), capsys.readouterr().err
