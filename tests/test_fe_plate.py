"""Finite-element plates against published values and the analytic plate.

Leissa, *Vibration of Plates* (NASA SP-160, 1969): the frequency parameter
``lambda = w a^2 sqrt(rho h / D)`` of a clamped square (Table 4.23) and of a free square with
nu = 0.3 (Table 4.61); the simply supported rectangle against ``modalctl``'s analytic Navier
solution (frequencies, shapes, the patches' pin-force gains and the sensors).
"""

from __future__ import annotations

import os
import time

import numpy as np
import pytest

from modalctl import forked
from modalctl.model import fe_plate
from modalctl.model.fe_plate import MATERIALS, FEPlate, Hole, Material, Outline, Support
from modalctl.model.modes import ModelError
from modalctl.model.structures import Plate, PlatePatch

LEISSA_CLAMPED_SQUARE = np.array([35.992, 73.413, 73.413, 108.27, 131.64, 132.24])
LEISSA_FREE_SQUARE_NU03 = np.array([13.468, 19.596, 24.270, 34.801, 34.801, 61.093])
STEEL = Material(200e9, 7850.0, 0.3)
PATCHES = tuple(PlatePatch((x - 0.006, x + 0.006), (y - 0.006, y + 0.006), f"patch{i + 1}")
                for i, (x, y) in enumerate([(-0.035, -0.022), (0.035, -0.022), (-0.035, 0.022), (0.035, 0.022)]))
SENSORS = ((0.01, 0.005), (0.02, 0.01))


def frequency_parameter(plate: FEPlate, frequencies: np.ndarray, side: float) -> np.ndarray:
    return 2 * np.pi * frequencies * side**2 * np.sqrt(plate.mass_per_area / plate.rigidity)


def test_clamped_square_matches_leissa_within_half_a_percent():
    plate = FEPlate(Outline.rectangle(0.1, 0.1), 1e-3, MATERIALS["glass"], {"rim": Support("clamped")})
    model, convergence = plate.modal_model(6, spacing=2e-3)
    lam = frequency_parameter(plate, model.frequencies, 0.1)
    assert np.all(np.abs(lam / LEISSA_CLAMPED_SQUARE - 1) < 0.005), lam
    assert convergence.converged and convergence.frequency_error.max() <= fe_plate.FREQUENCY_TOLERANCE
    assert np.all(np.diff(lam) >= -1e-9)


def test_free_square_matches_leissa_with_three_rigid_modes():
    plate = FEPlate(Outline.rectangle(0.1, 0.1), 1e-3, STEEL, {"rim": Support("free")})
    model, _ = plate.modal_model(6, spacing=2e-3)
    lam = frequency_parameter(plate, model.frequencies, 0.1)
    assert np.all(np.abs(lam / LEISSA_FREE_SQUARE_NU03 - 1) < 0.005), lam
    assert model.rigid_shapes.shape[0] == 3  # heave and two rockings, kept apart at zero frequency
    rigid = model.rigid_shapes * model.grid.mass @ model.rigid_shapes.T
    assert np.allclose(rigid, np.eye(3), atol=0.02)  # mass-normalized, on the grid as on the mesh


@pytest.mark.slow
def test_simply_supported_rectangle_matches_the_analytic_plate():
    """Frequencies within 0.1%, MAC >= 0.999 mode by mode, and the patches' gains and the
    sensors' readings as Navier's series gives them (up to each mode's sign)."""
    glass = MATERIALS["glass"]
    plate = FEPlate(Outline.rectangle(0.1, 0.07), 1e-3, glass, {"rim": Support("simply-supported")},
                    patches=PATCHES, sensors=SENSORS)
    model, _ = plate.modal_model(21, spacing=1e-3, tolerance=5e-4)
    exact = Plate(0.1, 0.07, 1e-3, glass.modulus, glass.density, glass.poisson).modal_model(
        21, nx=101, ny=71, patches=PATCHES, sensors=list(SENSORS))
    assert np.all(np.abs(model.frequencies / exact.frequencies - 1) < 1e-3)
    w = model.grid.mass
    overlap = model.shapes * w @ exact.shapes.T
    mac = np.diag(overlap) ** 2 / (np.einsum("kn,n,kn->k", model.shapes, w, model.shapes)
                                   * np.einsum("kn,n,kn->k", exact.shapes, w, exact.shapes))
    assert mac.min() >= 0.999
    sign = np.sign(np.diag(overlap))[:, None]
    scale = np.abs(exact.actuator_gains).max()
    assert np.allclose(sign * model.actuator_gains, exact.actuator_gains, atol=0.01 * scale)
    assert np.allclose(sign * model.sensor_gains, exact.sensor_gains, atol=0.01 * np.abs(exact.sensor_gains).max())


@pytest.mark.slow
def test_stiff_elastic_rim_tends_to_clamped_and_a_soft_one_lies_between():
    outline, glass = Outline.rectangle(0.1, 0.07), MATERIALS["glass"]
    clamped, _ = FEPlate(outline, 1e-3, glass, {"rim": Support("clamped")}).modal_model(4, spacing=2e-3)
    free, _ = FEPlate(outline, 1e-3, glass, {"rim": Support("free")}).modal_model(4, spacing=2e-3)
    stiff, _ = FEPlate(outline, 1e-3, glass, {"rim": Support("elastic", 1e13, 1e7)}).modal_model(4, spacing=2e-3)
    soft, _ = FEPlate(outline, 1e-3, glass, {"rim": Support("elastic", 1e6, 1.0)}).modal_model(4, spacing=2e-3)
    assert np.allclose(stiff.frequencies, clamped.frequencies, rtol=0.01)
    assert np.all(soft.frequencies < clamped.frequencies)
    assert soft.frequencies[0] > free.frequencies[0] * 0.5  # held by springs: not a free plate's rigid motion


@pytest.mark.slow
def test_rounded_panel_with_a_cut_out_weighs_what_it_should():
    """The lattice's weights add up to the panel's mass (holes and rounded corners cut out) and
    the shapes, normalized on the FE mass matrix, are normalized on the grid too."""
    outline = Outline.rectangle(0.09, 0.06, 0.008, holes=(Hole((0.025, 0.0), radius=0.006),))
    plate = FEPlate(outline, 0.7e-3, MATERIALS["glass"], patches=PATCHES[:2], sensors=((0.0, 0.0),))
    model, _ = plate.modal_model(8, spacing=1e-3)
    expected = plate.mass_per_area * (0.09 * 0.06 - (4 - np.pi) * 0.008**2 - np.pi * 0.006**2)
    assert model.grid.mass.sum() == pytest.approx(expected, rel=0.005)
    norms = np.einsum("kn,n,kn->k", model.shapes, model.grid.mass, model.shapes)
    assert np.allclose(norms, 1, atol=0.01)
    off = model.grid.mass == 0
    assert np.all(model.shapes[:, off] == 0) and np.any(off)
    assert np.all(np.abs(model.actuator_gains) > 0)


@pytest.mark.parametrize("build, words", [
    (lambda: Outline(np.array([[0, 0], [0.1, 0.1], [0.1, 0], [0, 0.1]])), "cross"),
    (lambda: Outline.rectangle(0.1, 0.07, holes=(Hole((0.045, 0.0), radius=0.01),)), "cuts the rim"),
    (lambda: FEPlate(Outline.rectangle(0.1, 0.07), 1e-3, MATERIALS["glass"],
                     patches=(PlatePatch((0.045, 0.06), (0.0, 0.01)),)), "not wholly on the plate"),
    (lambda: FEPlate(Outline.rectangle(0.1, 0.07, holes=(Hole((0.0, 0.0), radius=0.01),)), 1e-3, MATERIALS["glass"],
                     patches=(PlatePatch((-0.005, 0.005), (-0.005, 0.005)),)), "not wholly on the plate"),
    (lambda: FEPlate(Outline.rectangle(0.1, 0.07, holes=(Hole((0.0, 0.0), radius=0.003),)), 1e-3, MATERIALS["glass"],
                     patches=(PlatePatch((-0.005, 0.005), (-0.005, 0.005)),)), "not wholly on the plate"),
    (lambda: FEPlate(Outline.rectangle(0.1, 0.07), 1e-3, MATERIALS["glass"], {"north": Support("free")}), "no edge"),
    (lambda: Support("glued"), "not one of"),
])
def test_bad_geometry_is_refused_with_what_is_wrong(build, words):
    with pytest.raises(ModelError, match=words):
        build()


def test_a_band_too_high_for_the_mesh_budget_is_refused(monkeypatch):
    monkeypatch.setattr(fe_plate, "DOFS_MAX", 3000)
    plate = FEPlate(Outline.rectangle(0.1, 0.07), 1e-3, MATERIALS["glass"])
    with pytest.raises(ModelError, match="degrees of freedom"):
        plate.modal_model(band=40e3)



@pytest.mark.parametrize("failure", [ModelError("the fine mesh is refused"), KeyboardInterrupt()])
def test_the_coarse_mesh_s_child_is_stopped_when_the_fine_mesh_fails(monkeypatch, failure):
    """The fine mesh refused (DOFS_MAX, MODES_MAX, ARPACK) or Ctrl-C in this process while the
    child solves the coarse one: the child is killed, not left solving to a closed pipe."""
    here, children = os.getpid(), []

    def level(self, mesh, size, **_):
        if os.getpid() != here:
            time.sleep(60)  # the coarse mesh: still solving when the fine one fails
        raise failure

    def spy(job):
        work = forked.beside(job)
        children.append(work._process.pid)
        return work

    monkeypatch.setattr(FEPlate, "_level", level)
    monkeypatch.setattr(fe_plate, "beside", spy)
    plate = FEPlate(Outline.rectangle(0.1, 0.07), 1e-3, MATERIALS["glass"])
    start = time.monotonic()
    with pytest.raises(type(failure)):
        plate.modal_model(2, spacing=2e-3)
    assert time.monotonic() - start < 30 and len(children) == 1
    with pytest.raises(FileNotFoundError):  # killed and reaped
        open(f"/proc/{children[0]}/stat").close()


@pytest.mark.parametrize("support, lowest", [("clamped", 1405), ("free", 502)])
def test_a_band_below_the_lowest_mode_is_refused_naming_it(support, lowest):
    """--band 1Hz: the meshes find no mode below the band (times BAND_MARGIN), and nothing is
    left to converge (compare_levels read an empty mode list: IndexError)."""
    plate = FEPlate(Outline.rectangle(0.1, 0.07), 1e-3, MATERIALS["glass"], {"rim": Support(support)})
    with pytest.raises(ModelError, match=f"no mode below the band 1 Hz: this plate's lowest is at {lowest} Hz"):
        plate.modal_model(band=1.0, spacing=4e-3)


def test_covers_is_inclusive_on_every_side_and_contains_is_unchanged():
    outline = Outline.rectangle(0.1, 0.07, holes=(Hole((0.0, 0.0), radius=0.01),))
    rims = np.array([[0.05, 0.0], [-0.05, 0.0], [0.0, 0.035], [0.0, -0.035], [0.05, 0.035], [0.01, 0.0]])
    assert np.all(outline.covers(rims, 1e-9))
    assert not np.any(outline.covers(np.array([[0.05 + 1e-6, 0.0], [0.0, 0.035 + 1e-6], [0.0, 0.0]]), 1e-9))
    assert list(outline.contains(rims[:4])) == [False, True, False, True]  # the lattice's even-odd rule
    rounded = Outline.rectangle(0.1, 0.07, corner_radius=0.01)
    assert np.all(rounded.covers(np.array([[0.05, 0.0], [0.0, 0.035]]), 1e-9))
    assert not rounded.covers(np.array([[0.05, 0.035]]), 1e-9)[0]  # the cut corner is off the plate
    square_hole = Outline.rectangle(0.1, 0.07, holes=(Hole((0.0, 0.0), size=(0.02, 0.01)),))
    assert np.all(square_hole.covers(np.array([[0.01, 0.0], [0.0, -0.005]]), 1e-9))
    assert not square_hole.covers(np.array([[0.009, 0.0]]), 1e-9)[0]


def circle(radius: float, vertices: int) -> Outline:
    t = np.linspace(0, 2 * np.pi, vertices, endpoint=False)
    return Outline(radius * np.column_stack([np.cos(t), np.sin(t)]))


def test_n_modes_that_cut_a_degenerate_pair_converge():
    """A clamped circle's modes 2-3 and 4-5 are pairs: asked for 4, the 4th's partner was not
    solved, its shape (any of the pair's) failed the shape test on every mesh, and the command
    refused blaming the band. The pair's partner is solved, not kept. Against the clamped
    circular plate's lambda^2 = 10.2158 and 21.260 (Leissa, Table 2.1); the 100-gon inscribed."""
    plate = FEPlate(circle(0.04, 100), 1e-3, MATERIALS["glass"])
    model, convergence = plate.modal_model(4, spacing=4e-3)
    assert model.n_modes == 4 and convergence.shape_mac.min() >= fe_plate.SHAPE_TOLERANCE
    lam = 2 * np.pi * model.frequencies * 0.04**2 * np.sqrt(plate.mass_per_area / plate.rigidity)
    assert np.allclose(lam[:3], [10.2158, 21.260, 21.260], rtol=0.002), lam


@pytest.mark.slow
def test_an_outline_of_many_short_edges_is_refused_naming_them(tmp_path, capsys):
    """A 1000-vertex circle: its 0.25 mm edges make the mesh that fine along the rim, past the
    budget on the first refinement; the refusal named the band."""
    from modalctl.cli import main

    ring = ";".join(f"{40 * np.cos(a):.4f}mm,{40 * np.sin(a):.4f}mm" for a in np.linspace(0, 2 * np.pi, 1000,
                                                                                       endpoint=False))
    assert main(fe_command(tmp_path, "--outline", f"polygon:{ring}")) == 2
    err = capsys.readouterr().err
    assert "the outline's edges as short as 0.25 mm" in err and "give fewer vertices" in err


@pytest.mark.parametrize("side", ["right", "top", "left", "bottom"])
def test_a_patch_and_a_sensor_flush_with_any_rim_are_on_the_plate(side):
    """Flush with the right or top rim was refused, the same on the left or bottom accepted."""
    sign, axis = {"right": (1, 0), "top": (1, 1), "left": (-1, 0), "bottom": (-1, 1)}[side]
    half = (0.05, 0.035)[axis]
    inner, outer = sorted((sign * (half - 0.01), sign * half))
    span = (inner, outer), (-0.005, 0.005)
    patch = PlatePatch(*(span if axis == 0 else span[::-1]))
    sensor = (sign * half, 0.0) if axis == 0 else (0.0, sign * half)
    FEPlate(Outline.rectangle(0.1, 0.07), 1e-3, MATERIALS["glass"], patches=(patch,), sensors=(sensor,))
    beyond = (sensor[0] * 1.001, sensor[1] * 1.001)
    with pytest.raises(ModelError, match="not on the plate"):
        FEPlate(Outline.rectangle(0.1, 0.07), 1e-3, MATERIALS["glass"], sensors=(beyond,))


def test_flush_patches_and_sensors_on_opposite_rims_act_alike():
    """A free plate is symmetric about its centre: a patch and a sensor flush with the right rim
    drive and see each mode as their mirror images on the left do, up to the mode's sign."""
    right = PlatePatch((0.04, 0.05), (0.0, 0.01), "right")
    left = PlatePatch((-0.05, -0.04), (-0.01, 0.0), "left")
    plate = FEPlate(Outline.rectangle(0.1, 0.07), 1e-3, MATERIALS["glass"], {"rim": Support("free")},
                    patches=(right, left), sensors=((0.05, 0.02), (-0.05, -0.02)))
    model, _ = plate.modal_model(4, spacing=4e-3)
    assert np.all(np.abs(model.actuator_gains[:, 0]) > 0)
    gains = np.abs(model.actuator_gains)
    assert np.allclose(gains[:, 0], gains[:, 1], rtol=0.01)  # the mesh is not symmetric: 0.2% apart
    assert np.all(np.abs(model.sensor_gains[:, 0]) > 0)
    assert np.allclose(np.abs(model.sensor_gains[:, 0]), np.abs(model.sensor_gains[:, 1]), rtol=0.01)

def fe_command(tmp_path, *extra) -> list[str]:
    return ["model", "fe", "--thickness", "1mm", "--modes", "4", "--spacing", "4mm", "--no-plots",
            "--out", str(tmp_path / "plate.npz"), *extra]


@pytest.mark.parametrize("extra, words", [
    (["--outline", "polygon:0,0;100mm,100mm;100mm,0;0,100mm"], "cross"),
    (["--outline", "rect:100mm,70mm", "--hole", "circle:45mm,0,10mm"], "cuts the rim"),
    (["--outline", "rect:100mm,70mm", "--patch", "40mm,60mm,0,10mm"], "not wholly on the plate"),
    (["--outline", "rect:100mm,70mm", "--sensor", "0,50mm"], "not on the plate"),
    (["--outline", "rect:100mm,70mm", "--boundary", "north=free"], "no edge"),
    (["--outline", "rect:100mm,70mm", "--material", "E=70GPa,rho=2500kg/m^3,nu=0.6"], "poisson"),
    (["--outline", "rect:100mm,70mm,r=40mm"], "corner radius"),
    (["--outline", "circle:10mm"], "outline"),
])
def test_the_command_refuses_bad_geometry_with_exit_2(tmp_path, capsys, extra, words):
    from modalctl.cli import main

    try:
        code = main(fe_command(tmp_path, *extra))
    except SystemExit as refused:  # an option's own check, by argparse
        code = refused.code
    assert code == 2
    assert words in capsys.readouterr().err
    assert not (tmp_path / "plate.npz").exists()


@pytest.mark.parametrize("band", ["1Hz", "1300Hz"])
def test_the_command_refuses_a_band_below_the_lowest_mode_with_exit_2(tmp_path, capsys, band):
    from modalctl.cli import main

    args = [a for a in fe_command(tmp_path, "--outline", "rect:100mm,70mm") if a not in ("--modes", "4")]
    assert main([*args, "--band", band]) == 2
    err = capsys.readouterr().err
    assert "this plate's lowest is at 1405 Hz" in err and "Traceback" not in err
    assert not (tmp_path / "plate.npz").exists()


def test_the_command_refuses_a_band_the_mesh_budget_cannot_converge(tmp_path, capsys, monkeypatch):
    from modalctl.cli import main

    monkeypatch.setattr(fe_plate, "DOFS_MAX", 3000)
    args = [a for a in fe_command(tmp_path, "--outline", "rect:100mm,70mm") if a not in ("--modes", "4")]
    assert main([*args, "--band", "40kHz"]) == 2
    assert "degrees of freedom" in capsys.readouterr().err


@pytest.mark.slow
def test_a_model_file_from_the_command_plays_a_focus(tmp_path, capsys):
    """Geometry in, a model file out that ``run --model`` takes like a scene: a clamped rounded
    panel with a hole and two patches, a bump focused on the HIL."""
    import json

    from modalctl.cli import main
    from modalctl.model.modes import ModalModel

    code = main(fe_command(tmp_path, "--outline", "rect:90mm,60mm,r=6mm", "--hole", "circle:25mm,0,5mm",
                           "--patch=-35mm,-21mm,-20mm,-10mm", "--patch=-7mm,7mm,10mm,20mm", "--sensor", "0,0",
                           "--json"))
    assert code == 0
    summary = json.loads(capsys.readouterr().out)
    model = ModalModel.load(summary["model_file"])
    assert model.n_modes == 4 and model.actuator_gains.shape == (4, 2) and model.sensor_gains.shape == (4, 1)
    assert summary["convergence"]["converged"]
    run = ["run", "--model", summary["model_file"], "--shape", "bump", "--param", "width=50mm", "--param",
           "center=-10mm,0", "--modes", "all", "--focus-time", "25ms", "--json"]
    # two patches hold the 0.5 margin at 282 V only: above the patches' 70 V (the file's), refused
    assert main([*run, "--out", str(tmp_path / "margin")]) == 1
    assert "within voltage 70 V" in capsys.readouterr().err
    code = main([*run, "--margin", "none", "--out", str(tmp_path / "run")])
    assert code == 0, capsys.readouterr().err
    metrics = json.loads(capsys.readouterr().out)
    assert 0.5 < metrics["tau"] <= 1.0 and metrics["peak_voltage"] <= 70 * 1.001


@pytest.mark.slow
def test_a_finite_element_scene_is_solved_once_then_read_from_the_cache(tmp_path, monkeypatch):
    from modalctl.model.scenes import load_scene

    monkeypatch.setenv("MODALCTL_CACHE", str(tmp_path))
    first = load_scene("plate-glass-clamped", (26, 18))
    kept = list(tmp_path.glob("plate-glass-clamped-*.npz"))
    assert len(kept) == 1
    again = load_scene("plate-glass-clamped", (26, 18))
    assert np.array_equal(again.shapes, first.shapes) and np.array_equal(again.frequencies, first.frequencies)
    kept[0].write_bytes(b"not a model")  # a damaged entry is solved again and replaced
    assert np.allclose(load_scene("plate-glass-clamped", (26, 18)).frequencies, first.frequencies)
