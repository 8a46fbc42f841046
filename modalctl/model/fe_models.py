"""Finite-element plate models kept once solved, and grown when a shape needs more modes than they hold.

A finite-element model holds the modes below the band it was solved to; a shape finer than those
modes can draw needs more. The model's ``meta`` keeps the plate it was solved from (outline,
holes, supports, thickness, material, patches, sensors: :meth:`FEPlate.modal_model` writes them),
so :func:`grown` solves the same plate again to a higher band on the same grid, and keeps the
answer in the cache as the scenes are kept (:func:`solved`). :func:`drivable_band` says how far
growing makes sense: a patch of side ``s`` drives a bending wave of wavenumber ``k`` through the
moments along its edges, ``~ sin(k s / 2)``, whose first null is where the patch spans one whole
wavelength; and past a tenth of the DAC rate the drive is not drawn.
"""

from __future__ import annotations

import hashlib
import json
import warnings
from dataclasses import replace
from importlib import metadata
from pathlib import Path

import numpy as np

from modalctl.outdir import atomic

from .modes import ModalModel, ModelError

__all__ = ["solved", "plate_of", "grown", "drivable_band", "patch_band", "cache_dir", "SAMPLES_PER_PERIOD"]

SAMPLES_PER_PERIOD = 10  # the DAC draws a mode it samples at least ten times a period (DESIGN, chirp design)


def cache_dir() -> Path:
    """Where finite-element models are kept once solved: ``$MODALCTL_CACHE``, else
    ``$XDG_CACHE_HOME/modalctl``, else ``~/.cache/modalctl``."""
    import os

    if os.environ.get("MODALCTL_CACHE"):
        return Path(os.environ["MODALCTL_CACHE"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "modalctl"


def solved(name: str, plate, spacing: float, **options) -> ModalModel:
    """``plate``'s model (:meth:`~modalctl.model.fe_plate.FEPlate.modal_model` with ``options``) on a
    lattice of ``spacing`` (m), from the cache when this plate, these options and these solver
    versions were solved before (an ``.npz`` model file: no pickle). The grid's spacing is kept in
    the model's ``meta`` (``grid_spacing_m``), for :func:`grown`."""
    from . import fe_plate

    key = json.dumps({"plate": repr(plate), "spacing": spacing, "options": options, "solver": fe_plate.SOLVER_VERSION,
                      "versions": [metadata.version(p) for p in ("scikit-fem", "gmsh", "numpy", "scipy")]},
                     sort_keys=True)
    path = cache_dir() / f"{name}-{hashlib.sha256(key.encode()).hexdigest()[:16]}.npz"
    if path.is_file():
        try:
            return ModalModel.load(path)
        except ModelError:
            pass  # a damaged cache entry: solve again and replace it
    meta = {"name": name, "source": "finite elements", "grid_spacing_m": spacing}
    model, _ = plate.modal_model(spacing=spacing, meta=meta, **options)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic(path) as tmp:  # same suffix: save writes it as named
            model.save(tmp)
    except OSError as exc:
        warnings.warn(f"{name}: could not keep the solved model in {path.parent} ({exc}); it will be solved again",
                      UserWarning, stacklevel=3)
    return model


def plate_of(model: ModalModel):
    """The :class:`~modalctl.model.fe_plate.FEPlate` ``model`` was solved from, read back from its
    ``meta``; None for a model that is not a finite-element plate's (a beam, an identified model)."""
    meta = model.meta
    needed = ("outline_m", "supports", "thickness_m", "modulus_Pa", "density_kg_m3", "poisson", "actuators")
    if meta.get("structure") != "plate" or "finite-element" not in str(meta.get("model", "")) or \
            any(key not in meta for key in needed):
        return None
    from .fe_plate import ELEMENTS, FEPlate
    from .plate_geometry import Hole, Material, Outline, Support
    from .structures import PlatePatch

    try:  # a model file is outside input: a geometry that does not read back makes a model that cannot grow
        holes = tuple(Hole(tuple(h["centre_m"]), h["radius_m"], None if h["size_m"] is None else tuple(h["size_m"]),
                           h["corner_radius_m"]) for h in meta.get("holes", []))
        outline = Outline(np.asarray(meta["outline_m"], float), meta.get("corner_radius_m", 0.0), holes)
        element = next((name for name in ELEMENTS if name in meta["model"]), "15-parameter")
        return FEPlate(outline, meta["thickness_m"],
                       Material(meta["modulus_Pa"], meta["density_kg_m3"], meta["poisson"]),
                       {name: Support(**support) for name, support in meta["supports"].items()},
                       tuple(PlatePatch(tuple(a["xlim_m"]), tuple(a["ylim_m"]), a["name"]) for a in meta["actuators"]),
                       tuple(tuple(s["position_m"]) for s in meta.get("sensors", [])), element=element)
    except (KeyError, TypeError, ValueError, AttributeError, ModelError):
        return None


def _spacing(model: ModalModel) -> float:
    """The lattice spacing (m) of a finite-element model's grid: as kept in its ``meta``, else read
    from the grid (a file written before the spacing was kept)."""
    if "grid_spacing_m" in model.meta:
        return float(model.meta["grid_spacing_m"])
    x = np.unique(np.round(model.grid.points[:, 0], 12))
    return float(np.round(np.min(np.diff(x)), 9))  # a lattice of whole nanometres: 1 mm, not 0.999999999999994 mm


def drivable_band(model: ModalModel, sample_rate: float) -> float:
    """The highest frequency (Hz) a drive of ``model``'s plate can usefully reach (:func:`patch_band`)."""
    plate = plate_of(model)
    if plate is None:
        raise ModelError("this model is not a finite-element plate's: it cannot grow (solve it with modalctl model fe)")
    side = min(min(np.ptp(p.xlim), np.ptp(p.ylim)) for p in plate.patches) if plate.patches else plate.outline.diameter
    return patch_band(plate.rigidity, plate.mass_per_area, side, sample_rate)


def patch_band(rigidity: float, mass_per_area: float, side: float, sample_rate: float) -> float:
    """The highest frequency (Hz) a plate of bending ``rigidity`` (N m) and ``mass_per_area`` (kg/m^2)
    driven by patches whose smallest side is ``side`` (m) can usefully reach: where that side spans one
    bending wavelength (the first null of the pin-force gain ``sin(k s / 2)``: beyond it the moments
    along opposite edges cancel), and at most a tenth of the DAC's ``sample_rate`` (Hz)."""
    wavenumber = 2 * np.pi / side  # one wavelength across the patch
    omega = wavenumber**2 * np.sqrt(rigidity / mass_per_area)
    return float(min(omega / (2 * np.pi), sample_rate / SAMPLES_PER_PERIOD))


def grown(model: ModalModel, band: float) -> ModalModel:
    """``model``'s plate solved again with every mode below ``band`` (Hz), on the same grid points,
    with the same modal damping; kept in the cache like the scenes. ModelError when ``model`` is
    not a finite-element plate's or the grid would change."""
    plate = plate_of(model)
    if plate is None:
        raise ModelError("this model is not a finite-element plate's: it cannot grow (solve it with modalctl model fe)")
    name = str(model.meta.get("name", "plate"))
    bigger = solved(f"{name}-band{band:.0f}Hz", plate, _spacing(model), band=float(band),
                    damping=float(np.median(model.damping)))
    if bigger.grid.n != model.grid.n or not np.allclose(bigger.grid.points, model.grid.points, atol=1e-9):
        raise ModelError(f"{name}: solved again to {band:g} Hz, its grid changed ({bigger.grid.n} points against "
                         f"{model.grid.n}); the model cannot grow on this grid")
    return replace(bigger, meta={**bigger.meta, "name": name, "grown_from_band_hz": float(model.frequencies.max())})
