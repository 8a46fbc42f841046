"""Shape generators: the thesis's width convention, target zones, units, windows, sums, arrays."""

import numpy as np
import pytest
from scipy.signal.windows import tukey

from modalctl.model.modes import Grid
from modalctl.model.shape import ParamError, parse_params, tukey_window
from modalctl.model.structures import Plate
from modalctl.plugin.manager import get_shape

GRID = Grid.line(-0.0525, 0.0525, 1051, 0.0189)


def make(name, grid=GRID, **raw):
    generator = get_shape(name)
    return generator.generate(grid, **parse_params(generator, raw))


@pytest.mark.parametrize("name", ["sinc", "bump", "gaussian"])
def test_width_is_full_width_at_30_percent(name):
    shape = make(name, width="18mm", center="24mm", taper=0)
    values = np.interp([0.024 - 0.009, 0.024, 0.024 + 0.009], GRID.x, shape.values)
    assert values == pytest.approx([0.3 * 0.04, 0.04, 0.3 * 0.04], rel=1e-3)
    zone = GRID.x[shape.target_mask]
    assert zone.min() == pytest.approx(0.015, abs=2e-4) and zone.max() == pytest.approx(0.033, abs=2e-4)


def test_sinc_follows_thesis_equation():
    shape = make("sinc", width="25mm", center="-24mm", amplitude="40mm/s", taper=0)
    expected = 0.04 * np.sinc(3 * (GRID.x + 0.024) / (2 * 0.025))
    assert shape.values == pytest.approx(expected)


def test_bump_has_compact_support():
    shape = make("bump", width="25mm", taper=0)
    support = GRID.x[shape.values > 0]
    assert support.max() == pytest.approx(0.0125 / np.sqrt(1 - 1 / (1 - np.log(0.3))), abs=2e-4)
    assert np.all(shape.values >= 0)


def test_square_and_trapezoid():
    square = make("square", width="25mm", taper=0)
    assert np.all(square.values[np.abs(GRID.x) < 0.0124] == 0.04)
    assert np.all(square.values[np.abs(GRID.x) > 0.0126] == 0)
    trap = make("trapezoid", width="30mm", top="10mm", taper=0)
    assert np.interp([0.0, 0.005, 0.010, 0.015], GRID.x, trap.values) == pytest.approx([0.04, 0.04, 0.02, 0.0])
    with pytest.raises(ParamError, match="top"):
        make("trapezoid", width="10mm", top="20mm")


def test_units_or_si_numbers_give_the_same_field():
    a = make("sinc", width="18mm", center="24mm")
    b = make("sinc", width=0.018, center=0.024)
    assert a.values == pytest.approx(b.values, rel=1e-12, abs=1e-15)


def test_tukey_window_matches_scipy():
    grid = Grid.line(0, 1, 101, 1.0)
    assert tukey_window(grid, 0.3) == pytest.approx(tukey(101, 0.3), abs=1e-12)
    assert tukey_window(grid, 0.0) == pytest.approx(np.ones(101))


def test_taper_brings_field_to_zero_at_edges():
    shape = make("square", width="30mm", center="46mm", taper=0.2)
    assert shape.values[-1] == 0 and shape.values[0] == 0
    assert not shape.target_mask[-1]


def test_sum_of_shapes_is_sum_of_fields_and_union_of_zones():
    total = make("sum", parts="sinc(width=18mm,center=-24mm)+bump(width=25mm,center=24mm,amplitude=20mm/s)")
    a = make("sinc", width="18mm", center="-24mm")
    b = make("bump", width="25mm", center="24mm", amplitude="20mm/s")
    assert total.values == pytest.approx(a.values + b.values)
    assert np.array_equal(total.target_mask, a.target_mask | b.target_mask)
    with pytest.raises(ParamError, match="cannot read part"):
        make("sum", parts="sinc width=1mm")


def test_array_shape_from_values_and_files(tmp_path):
    values = np.sin(np.linspace(0, np.pi, GRID.n)) * 0.03
    direct = make("array", values=values)
    assert direct.values == pytest.approx(values)
    np.save(tmp_path / "field.npy", values)
    np.savetxt(tmp_path / "field.csv", values, delimiter=",")
    for path in ("field.npy", "field.csv"):
        assert make("array", values=str(tmp_path / path)).values == pytest.approx(values)
    with pytest.raises(ParamError, match="1051 points"):
        make("array", values=np.ones(10))


def test_shapes_on_a_plate():
    plate = Plate(0.1, 0.07, 0.001, 70e9, 2500)
    grid = plate.grid(101, 71)
    shape = make("sinc", grid=grid, width="15mm", center="20mm,-10mm", taper=0)
    peak = grid.points[np.argmax(shape.values)]
    assert peak == pytest.approx([0.02, -0.01], abs=1e-3)
    r = np.hypot(*(grid.points[shape.target_mask] - [0.02, -0.01]).T)
    assert r.max() <= 0.0075 + 1e-9
    with pytest.raises(ParamError, match="center"):
        make("sinc", grid=grid, width="15mm", center="1mm,2mm,3mm")
    # a focus off the plate (y beyond 35 mm) is refused, not planned on the pulse's far tail
    with pytest.raises(ParamError, match="off the structure.*-35 to 35 mm"):
        make("sinc", grid=grid, width="15mm", center="0mm,80mm")
    make("sinc", grid=grid, width="15mm", center="50mm,35mm")  # a corner is on the plate


def test_parameter_errors_list_what_is_accepted():
    with pytest.raises(ParamError, match="unknown parameter 'widht'.*accepted: width"):
        make("sinc", widht="18mm")
    with pytest.raises(ParamError, match="'width' is required"):
        make("sinc")
    with pytest.raises(ParamError, match="unknown unit"):
        make("sinc", width="18 furlongs")


def test_a_taper_that_moves_the_pulse_is_said():
    """Issue 26: a 20 mm bump at 48 mm on the 105 mm clamped beam peaked at 43.4 mm under the default
    taper, and runs measured against the moved target without a word."""
    import warnings

    from modalctl.model.scenes import load_scene
    from modalctl.plugins.shapes import TaperWarning

    grid = load_scene("thesis-al-cc", 211).grid
    bump = get_shape("bump")
    with pytest.warns(TaperWarning, match="moves the pulse's peak by 4.[0-9] mm"):
        shape = bump.generate(grid, **parse_params(bump, {"width": "20mm", "center": "48mm"}))
    assert abs(grid.x[np.argmax(shape.values)] - 0.048) > 3e-3  # independent: the peak did move
    with warnings.catch_warnings():
        warnings.simplefilter("error", TaperWarning)
        bump.generate(grid, **parse_params(bump, {"width": "20mm", "center": "0mm"}))  # far from the ends
        bump.generate(grid, **parse_params(bump, {"width": "20mm", "center": "48mm", "taper": "0"}))
