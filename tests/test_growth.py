"""Models that hold what the shape needs: a finite-element model grown to a higher band equals the
plate solved at that band directly, and growing stops, refusing, at the band the patches can drive."""

import numpy as np
import pytest

from modalctl.model.fe_models import drivable_band, grown, plate_of, solved
from modalctl.model.fe_plate import MATERIALS, FEPlate, Hole, Outline, Support
from modalctl.model.shape import Shape
from modalctl.model.structures import PlatePatch
from modalctl.options import PlanOptions
from modalctl.plan.growth import model_for, reach
from modalctl.plan.reduction import ReductionError

SPACING = 2e-3
pytestmark = pytest.mark.slow  # finite-element solves: first in the queue of make test's workers


@pytest.fixture(scope="module")
def plate():
    """A small rounded glass panel with a hole, a clamped rim but one free edge, two patches."""
    outline = Outline.rectangle(0.06, 0.04, 0.004, holes=(Hole((0.015, 0.0), radius=0.004),))
    return FEPlate(outline, 1e-3, MATERIALS["glass"], {"rim": Support("clamped"), "left": Support("free")},
                   patches=(PlatePatch((-0.02, -0.01), (-0.012, -0.004)), PlatePatch((0.0, 0.01), (0.004, 0.012))),
                   sensors=((0.0, 0.0),))


@pytest.fixture(scope="module")
def small(plate, tmp_path_factory):
    import os

    os.environ["MODALCTL_CACHE"] = str(tmp_path_factory.mktemp("cache"))
    return solved("small", plate, SPACING, band=8e3, damping=0.02)


def _bump(model, width: float) -> Shape:
    r = np.hypot(*(model.grid.points - [-0.01, 0.005]).T)
    values = np.where(r < width, np.cos(0.5 * np.pi * r / width) ** 2, 0.0) * (model.grid.mass > 0)
    return Shape(values, values > 0.3)


def test_the_plate_read_back_from_a_model_is_the_plate_it_was_solved_from(plate, small):
    back = plate_of(small)
    assert back.outline.holes == plate.outline.holes and back.supports == plate.supports
    np.testing.assert_array_equal(back.outline.vertices, plate.outline.vertices)
    assert [(p.xlim, p.ylim) for p in back.patches] == [(p.xlim, p.ylim) for p in plate.patches]
    assert back.sensors == plate.sensors and back.material == plate.material and back.thickness == plate.thickness


def test_a_grown_model_equals_the_plate_solved_at_that_band_directly(plate, small):
    bigger = grown(small, 14e3)
    direct, _ = plate.modal_model(band=14e3, spacing=SPACING, damping=0.02)
    assert bigger.n_modes == direct.n_modes > small.n_modes
    np.testing.assert_allclose(bigger.frequencies, direct.frequencies, rtol=1e-9)
    np.testing.assert_allclose(bigger.damping, 0.02)
    np.testing.assert_array_equal(bigger.grid.points, small.grid.points)
    # shapes equal up to sign (and within a cluster of equal frequencies, up to a rotation: none here)
    inner = lambda a, b: np.einsum("kn,kn,n->k", a, b, direct.grid.mass)  # noqa: E731
    overlap = np.abs(inner(bigger.shapes, direct.shapes)) / np.sqrt(inner(bigger.shapes, bigger.shapes)
                                                                     * inner(direct.shapes, direct.shapes))
    np.testing.assert_allclose(overlap, 1.0, atol=1e-6)
    np.testing.assert_allclose(np.abs(bigger.actuator_gains), np.abs(direct.actuator_gains), rtol=1e-6, atol=1e-9)


def test_a_shape_the_modes_cannot_draw_grows_the_model_until_they_do(small):
    shape = _bump(small, 0.012)
    before = reach(small, shape)
    options = PlanOptions(tau_min=min(0.98, before + 0.5 * (1 - before)))
    assert before < options.tau_min
    bigger, growth = model_for(small, shape, options)
    assert growth.modes == bigger.n_modes > small.n_modes and growth.tau >= options.tau_min
    assert reach(bigger, shape) == pytest.approx(growth.tau)
    assert model_for(small, shape, options.but(modes=9))[1] is None  # a mode set chosen by hand: no growth


def test_growing_stops_at_the_band_the_patches_can_drive_and_says_what_it_reached(small):
    limit = drivable_band(small, 1e7)  # a DAC fast enough that the patches bound it
    # the first null of a patch's pin-force gain: one bending wavelength across its smaller side (8 mm)
    wavelength = 2 * np.pi * (plate_of(small).rigidity / plate_of(small).mass_per_area) ** 0.25 / np.sqrt(2 * np.pi * limit)
    assert wavelength == pytest.approx(0.008)
    assert drivable_band(small, 1e5) == pytest.approx(1e4)  # a tenth of the DAC rate
    spike = Shape(np.eye(small.grid.n)[np.argmax(small.grid.mass)], np.eye(small.grid.n, dtype=bool)[0])
    with pytest.raises(ReductionError, match="the band its patches and the DAC can drive"):
        model_for(small, spike, PlanOptions(sample_rate=1.5e5))


def test_a_model_whose_geometry_does_not_read_back_is_not_grown(small):
    from dataclasses import replace

    for broken in ({"outline_m": "nonsense"}, {"supports": {"rim": {"kind": "glue"}}}, {"actuators": [{"x": 1}]},
                   {"thickness_m": float("nan")}):
        odd = replace(small, meta={**small.meta, **broken})
        assert plate_of(odd) is None
        assert model_for(odd, _bump(odd, 0.012), PlanOptions())[1] is None  # what it has, no traceback


def test_a_plate_continued_to_more_modes_is_grown_and_cut_to_them(small):
    from modalctl.model.scenes import continued

    richer = continued(small, 2 * small.n_modes)
    assert richer.n_modes == 2 * small.n_modes
    np.testing.assert_allclose(richer.frequencies[:small.n_modes], small.frequencies, rtol=1e-9)
    np.testing.assert_array_equal(richer.grid.points, small.grid.points)
    assert np.all(np.diff(richer.frequencies) >= 0)


def test_an_analytic_plate_scene_grows_with_its_plate_s_exact_modes_and_a_beam_does_not():
    """plate-glass (simply supported, analytic) draws a 30 mm bump at (-20, 5) mm to 0.968 with its 21
    modes: it grows to every mode of its plate below the band reached, the same model as the scene built
    with that many modes (frequencies from the textbook formula, an independent check), on the same grid;
    the patches' null and the DAC bound the band as for a finite-element plate. A beam's modes above the
    identified ones are an extrapolation: it is not grown."""
    from modalctl.model.scenes import grown_scene, load_scene, scene_band
    from modalctl.model.shape import parse_params
    from modalctl.plugin.manager import get_shape

    def shape(model, name, **params):
        generator = get_shape(name)
        return generator.generate(model.grid, **parse_params(generator, params))

    model = load_scene("plate-glass")
    bump = shape(model, "bump", width="30mm", center="-20mm,5mm")
    bigger, growth = model_for(model, bump, PlanOptions())
    assert growth.modes == bigger.n_modes > model.n_modes and growth.tau >= 0.98 > growth.tau_before
    direct = load_scene("plate-glass", modes=bigger.n_modes)
    np.testing.assert_array_equal(bigger.frequencies, direct.frequencies)
    np.testing.assert_array_equal(bigger.grid.points, model.grid.points)
    assert bigger.frequencies.max() <= growth.band_hz < np.sort(
        load_scene("plate-glass", modes=2 * bigger.n_modes).frequencies)[bigger.n_modes]  # every mode below the band
    d = 70e9 * 1e-3**3 / (12 * (1 - 0.22**2))  # glass 1 mm: E h^3 / 12 (1 - nu^2)
    m, n = np.array(bigger.meta["mode_indices"][-1], float)
    assert bigger.frequencies[-1] == pytest.approx(np.pi / 2 * ((m / 0.1) ** 2 + (n / 0.07) ** 2) * np.sqrt(d / 2.5))
    wavelength = 2 * np.pi * (d / 2.5) ** 0.25 / np.sqrt(2 * np.pi * scene_band(model, 1e8))  # 12 mm patches
    assert wavelength == pytest.approx(0.012) and scene_band(model, 5e5) == pytest.approx(5e4)
    assert grown_scene(model, 1.0).n_modes == model.n_modes  # never fewer than it has
    beam = load_scene("thesis-al-cc")
    sinc = shape(beam, "sinc", width="4mm")
    assert reach(beam, sinc) < 0.98  # below the default target, and still the beam's own modes
    assert model_for(beam, sinc, PlanOptions())[1] is None
