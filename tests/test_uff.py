"""UFF 58 read by its meaning: files written by pyuff here, with a known truth (a simply
supported plate's modes, analytic), in the forms commercial software exports."""

from __future__ import annotations

import json

import numpy as np
import pytest

from modalctl.cli import main
from modalctl.identify.frf import read_uff58
from modalctl.identify.survey import identify_frf
from modalctl.model.modes import Grid, ModelError

pyuff = pytest.importorskip("pyuff")

A, B = 0.1, 0.07  # plate (m)
MODES = [(1, 1, 700.0, 0.01), (2, 1, 1300.0, 0.01), (1, 2, 1900.0, 0.015)]
FREQS = np.arange(300.0, 2400.0, 1.0)
DENSITY = 2.5  # kg/m^2


def grid_points(nx=9, ny=7):
    x, y = np.meshgrid(np.linspace(0.005, A - 0.005, nx), np.linspace(0.005, B - 0.005, ny))
    return np.column_stack([x.ravel(), y.ravel()])


def shape(points, m, n):
    return np.sin(m * np.pi * points[:, 0] / A) * np.sin(n * np.pi * points[:, 1] / B)


def mobility(points):
    w = 2 * np.pi * FREQS
    h = np.zeros((len(points), FREQS.size), complex)
    for m, n, f, z in MODES:
        wk = 2 * np.pi * f
        h += np.outer(40 * shape(points, m, n), 1j * w / (wk**2 - w**2 + 2j * z * wk * w))
    return h


def write(path, points, values, *, func_type=4, ordinate=11, rsp_dir=3, ref_dir=3, order=None, xyz=None):
    """A UFF file: dataset 15 (nodes, optionally listed in ``order``) and one dataset 58 per node."""
    n = len(points)
    order = np.arange(n) if order is None else order
    xyz = np.column_stack([points, np.zeros(n)]) if xyz is None else xyz
    nodes = np.arange(1, n + 1)
    uff = pyuff.UFF(str(path))
    uff.write_sets(pyuff.prepare_15(node_nums=nodes[order], x=xyz[order, 0], y=xyz[order, 1], z=xyz[order, 2]),
                   mode="add")
    dirs = np.broadcast_to(rsp_dir, (n,))
    for i in order:
        uff.write_sets(pyuff.prepare_58(func_type=func_type, rsp_node=int(nodes[i]), rsp_dir=int(dirs[i]),
                                        ref_node=100, ref_dir=ref_dir, data=values[i], x=FREQS, id1="frf",
                                        rsp_ent_name="plate", ref_ent_name="plate", abscissa_spacing=1,
                                        abscissa_spec_data_type=18, ordinate_spec_data_type=ordinate,
                                        orddenom_spec_data_type=13), mode="add")
    return path


def check_identified(frf, points):
    """Three modes, shapes with MAC >= 0.99 against the analytic ones on the same points."""
    survey = identify_frf(frf, DENSITY, "auto")
    model = survey.model
    assert model.n_modes == 3
    assert np.allclose(model.frequencies, [m[2] for m in MODES], rtol=1e-4)
    for k, (m, n, _, _) in enumerate(MODES):
        a, b = model.shapes[k], shape(frf.points if frf.points.shape[1] == 2 else points, m, n)
        assert (a @ b) ** 2 / ((a @ a) * (b @ b)) >= 0.99
    # the same sign everywhere: the gain carries it; the field gain * shape is what was measured
    field = model.actuator_gains[0, 0] * model.shapes[0]
    assert np.corrcoef(field, shape(frf.points, 1, 1))[0, 1] > 0.99
    return survey


def test_mobility_on_a_plate_grid(tmp_path):
    points = grid_points()
    frf = read_uff58(write(tmp_path / "m.uff", points, mobility(points)))
    assert frf.points.shape == (63, 2) and frf.notes == ()
    survey = check_identified(frf, points)
    assert survey.model.grid.shape == (9, 7)  # a full rectangle: tensor Simpson weights
    assert np.isclose(survey.model.grid.mass.sum(), DENSITY * 0.09 * 0.06)


@pytest.mark.parametrize("kind, ordinate, power", [("accelerance", 12, 1), ("receptance", 8, -1)])
def test_accelerance_and_receptance_become_mobility(tmp_path, kind, ordinate, power):
    points = grid_points()
    values = mobility(points) * (2j * np.pi * FREQS) ** power
    frf = read_uff58(write(tmp_path / f"{kind}.uff", points, values, ordinate=ordinate))
    assert np.allclose(frf.values, mobility(points), rtol=1e-5, atol=1e-9)
    assert any(kind in note for note in frf.notes)
    survey = check_identified(frf, points)
    assert any(kind in note for note in survey.notes)


def test_sensors_along_minus_z_are_turned(tmp_path):
    points = grid_points()
    dirs = np.where(np.arange(len(points)) % 3 == 0, -3, 3)  # a third of the sensors mounted upside down
    values = mobility(points) * np.sign(dirs)[:, None]
    frf = read_uff58(write(tmp_path / "z.uff", points, values, rsp_dir=dirs))
    assert np.allclose(frf.values, mobility(points), rtol=1e-5, atol=1e-9)
    assert any("negative direction" in note for note in frf.notes)
    check_identified(frf, points)


def test_nodes_in_any_order_and_3d_coordinates(tmp_path):
    points = grid_points()
    rng = np.random.default_rng(1)
    shuffled = write(tmp_path / "s.uff", points, mobility(points), order=rng.permutation(len(points)))
    frf = read_uff58(shuffled)
    assert np.allclose(frf.points, points)  # sorted back: x fastest, then y
    check_identified(frf, points)
    # a plate measured in a frame where it lies in the x-z plane (y constant): 2-D coordinates
    xz = np.column_stack([points[:, 0], np.full(len(points), 0.3), points[:, 1]])
    frf = read_uff58(write(tmp_path / "xz.uff", points, mobility(points), xyz=xz))
    assert frf.points.shape == (63, 2)
    assert np.allclose(frf.points, points)
    # a beam listed with decreasing x
    line = np.column_stack([np.linspace(0.1, 0.0, 21), np.zeros(21)])
    frf = read_uff58(write(tmp_path / "line.uff", line, mobility(np.column_stack([line[:, 0], np.full(21, B / 2)])),
                           xyz=np.column_stack([line, np.zeros(21)])))
    assert frf.points.shape == (21, 1) and np.all(np.diff(frf.points[:, 0]) > 0)


def test_scattered_plate_points_get_delaunay_areas(tmp_path):
    rng = np.random.default_rng(2)
    points = np.column_stack([rng.uniform(0.005, A - 0.005, 90), rng.uniform(0.005, B - 0.005, 90)])
    grid = Grid.measured(points, DENSITY)
    assert grid.shape is None
    hull = __import__("scipy.spatial", fromlist=["ConvexHull"]).ConvexHull(points).volume  # area in 2-D
    assert np.isclose(grid.mass.sum(), DENSITY * hull)
    frf = read_uff58(write(tmp_path / "scatter.uff", points, mobility(points)))
    check_identified(frf, points)


@pytest.mark.parametrize("func_type, name", [(1, "time response"), (2, "auto-spectrum"), (3, "cross-spectrum"),
                                             (9, "power spectral density")])
def test_anything_but_an_frf_is_refused_by_name(tmp_path, capsys, func_type, name):
    points = grid_points(4, 3)
    path = write(tmp_path / "x.uff", points, mobility(points), func_type=func_type)
    with pytest.raises(ModelError, match=f"{name}.*function type {func_type}"):
        read_uff58(path)
    out = tmp_path / "model.npz"
    assert main(["identify", "--frf", str(path), "--mass-per-area", "2.5kg/m^2", "--out", str(out),
                 "--no-plots"]) == 2
    assert name in capsys.readouterr().err
    assert not out.exists()


def test_cli_identifies_a_plate_from_accelerance(tmp_path, capsys):
    points = grid_points()
    path = write(tmp_path / "acc.uff", points, mobility(points) * 2j * np.pi * FREQS, ordinate=12)
    assert main(["identify", "--frf", str(path), "--mass-per-area", "2.5kg/m^2", "--out", str(tmp_path / "plate.npz"),
                 "--no-plots", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["modes"] == 3 and any("accelerance" in n for n in summary["notes"])
    assert np.allclose(summary["frequencies_hz"], [m[2] for m in MODES], rtol=1e-4)


def test_mixed_or_unknown_contents_are_refused(tmp_path):
    points = grid_points(4, 3)
    with pytest.raises(ModelError, match="data type 15"):
        read_uff58(write(tmp_path / "p.uff", points, mobility(points), ordinate=15))  # pressure
    with pytest.raises(ModelError, match="directions"):
        read_uff58(write(tmp_path / "d.uff", points, mobility(points), rsp_dir=np.r_[3, 1, np.full(10, 3)]))


def test_a_beam_along_a_diagonal_is_a_line(tmp_path):
    t = np.linspace(0.0, 0.1, 21)
    xyz = np.column_stack([t * 0.6, t * 0.8, np.zeros(21)])  # 100 mm along a diagonal of the x-y plane
    values = mobility(np.column_stack([t, np.full(21, B / 2)]))
    frf = read_uff58(write(tmp_path / "diag.uff", xyz[:, :2], values, xyz=xyz))
    assert frf.points.shape == (21, 1)
    assert np.allclose(np.diff(frf.points[:, 0]), 0.005)  # distances along the line kept


@pytest.mark.parametrize("options, named", [(["--snr", "40"], "--snr"), (["--snr", "20"], "--snr"),
                                            (["--averages", "1"], "--averages")])
def test_a_sweep_option_given_with_a_file_is_refused_even_at_its_default(tmp_path, capsys, options, named):
    """``--snr 40`` (the simulator's default) with --frf was taken as not given, and ignored."""
    points = grid_points()
    path = write(tmp_path / "m.uff", points, mobility(points))
    out = tmp_path / "plate.npz"
    assert main(["identify", "--frf", str(path), "--mass-per-area", "2.5kg/m^2", "--out", str(out), "--no-plots",
                 *options]) == 2
    err = capsys.readouterr().err
    assert named in err and "not apply to --frf" in err and not out.exists()


def test_an_frf_no_measurement_reaches_is_refused_before_the_fit(tmp_path):
    """FRFs of 1e300 (finite) had reached LSCF, whose sums of squares overflow: a singular solve, exit 4."""
    points = grid_points(4, 3)
    with pytest.raises(ModelError, match="stays below"):
        read_uff58(write(tmp_path / "h.uff", points, mobility(points) * 1e298))
    assert read_uff58(write(tmp_path / "s.uff", points, mobility(points) * 1e6)).values.shape[0] == 12
