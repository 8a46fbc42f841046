"""Named scenes: ready-made modal models of the thesis's prototypes and of a plate.

The thesis presets use the tabulated resonance frequencies and damping ratios
(``modalctl/data/thesis_tables.json``, a copy of the project's transcription of the thesis
tables) with analytic mode shapes of the stated boundary conditions.

Gain scale. The printed modal gains are only relative (their units and scale disagree
between tables), so actuator gains come from the pin-force model of PZT-5A patches
0.2 mm thick (d31 = 171 pm/V, E = 61 GPa) bonded on the beam: a physical scale in SI units,
consistent across scenes, that puts drive voltages in the tens of volts for the thesis's
40 mm/s pulses, the range of the thesis's amplifiers. The patch layout is stated in each
scene's ``meta`` (the thesis does not print it).
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, replace
from functools import lru_cache
from importlib import resources
from typing import Callable

import numpy as np

from modalctl.options import MODES_MAX

from .fe_models import cache_dir, grown, patch_band, plate_of, solved
from .fe_plate import MATERIALS, FEPlate, Hole, Outline, Support
from .modes import ModalModel, ModelError
from .projection import gram
from .structures import Beam, BeamPatch, Plate, PlatePatch

__all__ = ["Scene", "SCENES", "load_scene", "continued", "thesis_tables", "UnknownScene", "cache_dir"]


class UnknownScene(LookupError):
    """A scene name that is not defined."""


@lru_cache(maxsize=None)
def thesis_tables() -> dict:
    """The transcribed thesis tables (structures, experiments, shape definitions)."""
    return json.loads(resources.files("modalctl").joinpath("data/thesis_tables.json").read_text())


def _beam_from_table(key: str) -> tuple[Beam, dict]:
    s = thesis_tables()["structures"][key]
    beam = Beam(s["length_m"], s["width_m"], s["thickness_m"], s["material"]["E_Pa"], s["material"]["rho_kg_m3"],
                s["boundary"])
    return beam, s


def _even_patches(length: float, count: int, patch_length: float) -> list[BeamPatch]:
    centres = -length / 2 + (np.arange(count) + 0.5) * length / count
    return [BeamPatch(c - patch_length / 2, c + patch_length / 2, f"patch{i + 1}") for i, c in enumerate(centres)]


def _fill_missing(beam: Beam, numbers: np.ndarray, freqs: list, zetas: list) -> tuple[np.ndarray, np.ndarray, list]:
    """Fill modes the thesis could not identify: frequency from the analytic one scaled by the
    ratio measured/analytic of the nearest identified modes, damping as their mean."""
    analytic = beam.frequencies(int(numbers.max()))[numbers - 1]
    f, z = np.array(freqs, dtype=float), np.array(zetas, dtype=float)
    known = np.isfinite(f)
    estimated = []
    for i in np.flatnonzero(~known):
        near = np.argsort(np.abs(np.flatnonzero(known) - i))[:2]
        idx = np.flatnonzero(known)[near]
        f[i] = analytic[i] * np.mean(f[idx] / analytic[idx])
        z[i] = np.nanmean(z[idx]) if not np.isfinite(z[i]) else z[i]
        estimated.append(int(numbers[i]))
    z[~np.isfinite(z)] = np.nanmedian(z)
    return f, z, estimated


def _continued(numbers: np.ndarray, modes: int | None) -> np.ndarray:
    """Elastic mode ``numbers`` cut or continued to ``modes`` of them, by the sequence's last step
    (a free-free beam's symmetric modes go by two)."""
    if modes is None:
        return numbers
    step = int(numbers[-1] - numbers[-2]) if numbers.size > 1 else 1
    return np.r_[numbers, numbers[-1] + step * np.arange(1, max(modes - numbers.size, 0) + 1)][:modes]


def _thesis_beam(key: str, name: str, patches: Callable[[Beam], list], sensors, n_points: int,
                 modes: int | None = None) -> ModalModel:
    """A thesis beam's identified modes, or ``modes`` of them: past the table, the analytic modes
    with frequencies scaled by the highest identified modes' ratio measured / analytic and their
    damping (the beam continued, a truth richer than the model)."""
    beam, table = _beam_from_table(key)
    rows = table["modes"]
    numbers = _continued(np.array([r["n"] for r in rows]), modes)
    freqs = [r.get("f_hz") if r.get("f_hz") is not None else np.nan for r in rows][:numbers.size]
    zetas = [r.get("zeta") if r.get("zeta") is not None else np.nan for r in rows][:numbers.size]
    beyond = numbers.size - len(freqs)
    f, z, estimated = _fill_missing(beam, numbers, freqs + [np.nan] * beyond, zetas + [np.nan] * beyond)
    meta = {"name": name, "source": f"thesis tables: {key}", "what": table["what"],
            "estimated_modes": estimated[:len(estimated) - beyond],
            "estimated_note": "frequency scaled from the analytic one by the nearest identified modes' ratio",
            **({"continued_modes": estimated[len(estimated) - beyond:]} if beyond > 0 else {}),
            "thesis_gain": [r.get("gain") for r in rows], "thesis_gain_unit": table["gain_unit_as_printed"]}
    return beam.modal_model(numbers, n_points=n_points, patches=patches(beam), sensors=sensors,
                            frequencies=f, damping=z, meta=meta)


def _al_cc(n_points, modes=None):
    return _thesis_beam("al_cc_beam", "thesis-al-cc", lambda b: _even_patches(b.length, 8, 0.010),
                        [-0.036, -0.012, 0.012, 0.036], n_points, modes)


def _rython_pp(n_points, modes=None):
    # mode 1 was not identified (printed gain 0): its frequency is estimated like the thesis's FEM value
    return _thesis_beam("rython_pp_beam", "thesis-rython-pp",
                        lambda b: [BeamPatch(-b.length / 2 + 0.002, -b.length / 2 + 0.017, "patch1")],
                        [0.0], n_points, modes)


def _al_ff(n_points, modes=None):
    # the thesis models the nine symmetric elastic modes, numbered 1, 3, ..., 17
    return _thesis_beam("al_ff_beam", "thesis-al-ff", lambda b: _even_patches(b.length, 6, 0.012),
                        [0.0, 0.02], n_points, modes)


def _patches(centres, width: float, height: float) -> list[PlatePatch]:
    """Rectangular patches ``width`` x ``height`` (m) centred at ``centres`` [(x, y), ...] (m)."""
    return [PlatePatch((x - width / 2, x + width / 2), (y - height / 2, y + height / 2), f"patch{i + 1}")
            for i, (x, y) in enumerate(centres)]


PLATE_PATCHES = _patches([(-0.035, -0.022), (0.035, -0.022), (-0.035, 0.022), (0.035, 0.022)], 0.012, 0.012)
PLATE_SENSORS = [(0.0, 0.0), (0.02, 0.01)]


def _plate(n_points, modes=None):
    nx, ny = (101, 71) if n_points is None else n_points
    plate = Plate(0.100, 0.070, 0.001, 70e9, 2500, 0.22)  # glass, the size of a small touch screen
    return plate.modal_model(modes or 21, nx=nx, ny=ny, patches=PLATE_PATCHES, sensors=PLATE_SENSORS,
                             damping=0.01, meta={"name": "plate-glass", "source": "analytic"})


def _spacing(plate: FEPlate, n_points) -> float:
    """The lattice spacing (m) that puts ``n_points`` = (nx, ny) across the plate's bounding box."""
    span = np.ptp(plate.outline.vertices, axis=0)
    return float(max(span[0] / (n_points[0] - 1), span[1] / (n_points[1] - 1)))


def _fe_scene(name: str, plate: FEPlate, n_points, **options) -> ModalModel:
    """The FE plate's model on a lattice of ``n_points``, solved once and kept (:func:`solved`),
    its actuators' safe voltage in its ``meta`` (a model cached before it was kept gets it here)."""
    model = solved(name, plate, _spacing(plate, n_points), **options)
    return replace(model, meta={**model.meta, **plate.piezo.voltage_meta()})


#: The clamped plate's patches (x, y centres, m): inward of plate-glass's, where a clamped plate's
#: low modes bend. At plate-glass's places they sit on the clamped (2, 1) mode's line of zero
#: curvature: its gain would be 0.12 against 8 to 150 (1e-3 sqrt(kg) m/s^2/V) for the others.
CLAMPED_PATCHES = [(-0.025, -0.015), (0.025, -0.015), (-0.025, 0.015), (0.025, 0.015)]


def _plate_clamped(n_points, modes=None):
    """plate-glass held on a clamped rim instead of simply supported: the same plate and sensors,
    its four patches moved inward (:data:`CLAMPED_PATCHES`)."""
    plate = FEPlate(Outline.rectangle(0.100, 0.070), 0.001, MATERIALS["glass"], {"rim": Support("clamped")},
                    patches=tuple(_patches(CLAMPED_PATCHES, 0.012, 0.012)), sensors=tuple(PLATE_SENSORS))
    return _fe_scene("plate-glass-clamped", plate, n_points or (101, 71), n_modes=modes or 21, damping=0.01)


#: The touch panel's six patches (x, y centres, m): two rows along its long edges.
PANEL_PATCHES = [(-0.040, -0.024), (0.0, -0.024), (0.040, -0.024), (-0.040, 0.024), (0.0, 0.024), (0.040, 0.024)]


def _panel(n_points, modes=None):
    """A rounded touch panel: 120 x 70 x 1 mm glass, 8 mm corners, glued (clamped) on its rim, a
    rounded 20 x 10 mm slot cut out near one end, six 14 x 10 mm patches; the modes below 12 kHz."""
    outline = Outline.rectangle(0.120, 0.070, 0.008, holes=(Hole((0.042, 0.0), size=(0.020, 0.010),
                                                                  corner_radius=0.004),))
    plate = FEPlate(outline, 0.001, MATERIALS["glass"], {"rim": Support("clamped")},
                    patches=tuple(_patches(PANEL_PATCHES, 0.014, 0.010)), sensors=((0.0, 0.0), (-0.02, 0.01)))
    solve = {"band": 12e3} if modes is None else {"n_modes": modes}
    return _fe_scene("panel-rounded", plate, n_points or (121, 71), **solve, damping=0.01)


@dataclass(frozen=True)
class Scene:
    """A named model builder; ``build(n_points, modes=None)`` returns its :class:`ModalModel`
    (``modes``: that many of the structure's modes instead of the scene's own)."""

    name: str
    summary: str
    build: Callable[..., ModalModel]
    default_points: object


SCENES = {s.name: s for s in [
    Scene("thesis-al-cc", "aluminium beam 105x7x1 mm, clamped-clamped, 21 modes (mode 18 estimated), 8 patches",
          _al_cc, 1051),
    Scene("thesis-rython-pp", "Rython beam 140x6x5 mm, pinned-pinned, 31 modes, 1 patch near a hinge",
          _rython_pp, 1401),
    Scene("thesis-al-ff", "aluminium beam 100x6x2 mm, free-free, 9 symmetric modes, 6 patches",
          _al_ff, 1001),
    Scene("plate-glass", "glass plate 100x70x1 mm, simply supported, 21 modes, 4 patches", _plate, (101, 71)),
    Scene("plate-glass-clamped", "plate-glass clamped on its rim (finite elements), 21 modes, 4 patches inward",
          _plate_clamped, (101, 71)),
    Scene("panel-rounded", "touch panel 120x70x1 mm glass, 8 mm corners, a 20x10 mm slot, clamped rim (finite "
          "elements), modes below 12 kHz, 6 patches", _panel, (121, 71)),
]}


#: Largest error of the modes' orthonormality a grid may leave (a coarser grid cannot draw them).
ORTHONORMAL_TOLERANCE = 0.05


def load_scene(name: str, n_points=None, modes: int | None = None) -> ModalModel:
    """Build the scene ``name`` (see :data:`SCENES`); ``n_points`` overrides its grid size, ``modes``
    the count of its structure's modes (the lowest; a truth richer than the scene: the grid is not
    asked to draw them)."""
    if name not in SCENES:
        raise UnknownScene(f"unknown scene {name!r}; available scenes: {', '.join(SCENES)}")
    scene = SCENES[name]
    if modes is not None and not 1 <= modes <= MODES_MAX:
        raise ModelError(f"{name}: between 1 and {MODES_MAX} modes, got {modes!r}")
    if n_points is None:
        return scene.build(scene.default_points, modes)
    if np.ndim(scene.default_points) != np.ndim(n_points):
        raise ModelError(f"{name}: its grid is given as {scene.default_points!r} points, got {n_points!r}")
    model = scene.build(n_points, modes)
    drawn = resolved_modes(model)
    if drawn == model.n_modes or modes is not None:
        return model
    if drawn == 0:
        raise ModelError(f"{name} on {n_points!r} points: the grid is too coarse to draw even its first mode; use "
                         f"more points (the default is {scene.default_points!r})")
    warnings.warn(f"{name} on {n_points!r} points: the grid draws only the first {drawn} of its {model.n_modes} modes "
                  f"(beyond, their inner products on it are off by more than {ORTHONORMAL_TOLERANCE:g}); the model "
                  f"keeps those {drawn}. The default is {scene.default_points!r} points", UserWarning, stacklevel=2)
    return model.select(np.arange(drawn))


def continued(model: ModalModel, modes: int) -> ModalModel:
    """The structure ``model`` describes with its ``modes`` lowest modes, on the same grid, actuators
    and sensors: a truth richer than the model (the modes it leaves out, spillover's cause). A
    finite-element plate's is solved again to a higher band (:func:`~.fe_models.grown`); a scene's
    is built with more modes (a thesis beam continued by its analytic shapes, their frequencies
    scaled by the highest identified modes' ratio measured / analytic). ModelError for any other
    model (an identified one: give the truth as a model file) or when the grid would change."""
    if not model.n_modes <= modes <= MODES_MAX:
        raise ModelError(f"a truth continues the model's {model.n_modes} modes: between {model.n_modes} and "
                         f"{MODES_MAX} modes, got {modes!r}")
    name = str(model.meta.get("name"))
    if plate_of(model) is not None:
        richer, band = model, float(model.frequencies.max())
        while richer.n_modes < modes:  # a plate's modes grow about in proportion to the band (Weyl)
            band *= max(1.2, 1.1 * modes / richer.n_modes)
            richer = grown(model, band)
        richer = richer.select(np.arange(modes))
    elif name in SCENES:  # on the model's own grid (a beam's count of points, a plate's lattice)
        richer = load_scene(name, model.grid.shape or model.grid.n, modes=modes)
    else:
        raise ModelError(f"model {name!r} is neither a scene nor a finite-element plate's: it cannot be continued to "
                         f"{modes} modes (give the truth as a model file)")
    same = richer.grid.n == model.grid.n and np.allclose(richer.grid.points, model.grid.points, atol=1e-9)
    if not same:
        raise ModelError(f"{name} continued to {modes} modes lies on another grid ({richer.grid.n} points against "
                         f"{model.grid.n}): build the model on the scene's default grid")
    return richer


def analytic_plate_of(model: ModalModel) -> Plate | None:
    """The simply supported plate an analytic plate scene's model was built from (from its ``meta``),
    or None for any other model."""
    meta = model.meta
    if meta.get("structure") != "plate" or meta.get("source") != "analytic" or meta.get("name") not in SCENES:
        return None
    return Plate(meta["a_m"], meta["b_m"], meta["thickness_m"], meta["modulus_Pa"], meta["density_kg_m3"],
                 meta["poisson"])


def scene_band(model: ModalModel, sample_rate: float) -> float:
    """The highest frequency (Hz) a drive of an analytic plate scene can usefully reach
    (:func:`~.fe_models.patch_band`, its smallest patch's side); ModelError for another model."""
    plate = _plate_scene(model)
    sides = [min(np.ptp(a["xlim_m"]), np.ptp(a["ylim_m"])) for a in model.meta.get("actuators", [])]
    return patch_band(plate.rigidity, plate.mass_per_area, min(sides, default=min(plate.a, plate.b)), sample_rate)


def grown_scene(model: ModalModel, band: float) -> ModalModel:
    """An analytic plate scene's model with every mode of its plate below ``band`` (Hz), on the same
    grid: the scene built with more modes (the plate's are exact at any band; the grid is not asked
    to draw them, as for a richer truth). ModelError for another model."""
    plate = _plate_scene(model)
    count = model.n_modes
    while (frequencies := plate.frequencies(plate.mode_indices(count)))[-1] < band and count < MODES_MAX:
        count = min(2 * count, MODES_MAX)  # enough of the plate's modes to pass the band
    below = int(np.count_nonzero(frequencies < band))
    return load_scene(str(model.meta["name"]), model.grid.shape or model.grid.n, modes=max(below, model.n_modes))


def _plate_scene(model: ModalModel) -> Plate:
    """:func:`analytic_plate_of`, ModelError where there is none: the model cannot grow."""
    plate = analytic_plate_of(model)
    if plate is None:
        raise ModelError("this model is not an analytic plate scene's: it cannot grow")
    return plate


def resolved_modes(model: ModalModel, tolerance: float = None) -> int:
    """How many of the model's first modes its grid can draw: the largest n for which the first n
    are orthonormal on the grid within ``tolerance`` (default :data:`ORTHONORMAL_TOLERANCE`); a
    grid too coarse for a mode aliases it onto the others."""
    tolerance = ORTHONORMAL_TOLERANCE if tolerance is None else tolerance
    error = np.abs(gram(model.shapes, model.grid.mass) - np.eye(model.n_modes))
    first = np.array([error[:n, :n].max() for n in range(1, model.n_modes + 1)])  # grows with n
    return int(np.count_nonzero(first <= tolerance))
