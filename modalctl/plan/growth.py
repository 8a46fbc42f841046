"""Models that hold what the shape needs: a plate's model grown until its modes draw the shape.

"Model no more than a scene needs" means no less either. A finite-element scene or model file
holds the modes below the band it was solved to; when even all of them miss the accuracy target
(a 25 mm bump on panel-rounded's 22 modes below 12 kHz reaches tau 0.957 < 0.98), the plate is
solved again to a band :data:`GROWTH` times higher (:func:`modalctl.model.fe_models.grown`, kept
in the cache), until the target is met or the band the patches and the DAC can drive is reached
(:func:`modalctl.model.fe_models.drivable_band`): then the refusal says what the largest model
reaches. An analytic plate scene (plate-glass) grows the same way, built with its plate's modes below
the higher band (:func:`modalctl.model.scenes.grown_scene`). Other models (beams, whose modes above
the identified ones are an extrapolation; identified ones) are what they are.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Callable

import numpy as np

from modalctl.model.fe_models import drivable_band, grown, plate_of
from modalctl.model.scenes import analytic_plate_of, grown_scene, scene_band
from modalctl.model.metrics import tau
from modalctl.model.modes import ModalModel
from modalctl.model.projection import project
from modalctl.model.shape import Shape
from modalctl.options import PlanOptions

from .reduction import ReductionError

__all__ = ["Growth", "model_for", "reach", "GROWTH"]

GROWTH = 1.5  # each step's band over the last's: about 1.5x the modes (Weyl: count grows with the band)


@dataclass(frozen=True)
class Growth:
    """How a model grew for a shape.

    Attributes
    ----------
    from_band_hz, band_hz : float
        The highest mode's frequency before and after.
    from_modes, modes : int
    tau_before, tau : float
        What all the modes reach on the shape, before and after.
    limit_hz : float
        The band growing stops at (:func:`~modalctl.model.fe_models.drivable_band`).
    reason : str
    """

    from_band_hz: float
    band_hz: float
    from_modes: int
    modes: int
    tau_before: float
    tau: float
    limit_hz: float
    reason: str

    def to_dict(self) -> dict:
        return asdict(self)


def reach(model: ModalModel, shape: Shape) -> float:
    """tau (Eq 4.2) of the shape drawn with every mode of ``model``: the best any mode set reaches."""
    coefficients = project(shape.values, model.shapes, model.grid.mass)
    return float(tau(shape.values, model.shapes.T @ coefficients))


def model_for(model: ModalModel, shape: Shape, options: PlanOptions = PlanOptions(),
              say: Callable[[str], None] | None = None) -> tuple[ModalModel, Growth | None]:
    """``model``, or ``model`` grown until its modes reach ``options.tau_min`` on ``shape`` (an
    automatic mode set on a plate's model only: a finite-element one or an analytic plate scene's); the
    growth, or None.

    ``say`` hears each step (a solve can take seconds). Raises :class:`ReductionError` when even
    the model grown to the drivable band misses the target, with what it reaches.
    """
    before = reach(model, shape)
    ways = _ways_to_grow(model)
    if options.modes != "auto" or options.tau_min is None or before >= options.tau_min or ways is None:
        return model, None
    band_of, grown_to = ways
    limit = band_of(model, options.sample_rate)
    first = float(model.frequencies.max())
    why = (f"its {model.n_modes} modes below {first:.0f} Hz reach tau {before:.3f} on the shape, below the target "
           f"{options.tau_min:g}")
    band, bigger, reached = first, model, before
    while band < limit * (1 - 1e-6):
        band = min(limit, float(round(band * GROWTH)))  # whole hertz: the cache's key and the mesh do not
        # follow the last bits of the model's top frequency (they moved gmsh's mesh by 18 of 6781 dofs)
        if say is not None:
            say(f"{why}: solving the plate again to {band:.0f} Hz")
        bigger = grown_to(model, band)
        reached = reach(bigger, shape)
        if reached >= options.tau_min:
            return bigger, Growth(first, float(bigger.frequencies.max()), model.n_modes, bigger.n_modes, before,
                                  reached, limit, why)
    raise ReductionError(f"{why}; grown to {limit:.0f} Hz (the band its patches and the DAC can drive), its "
                         f"{bigger.n_modes} modes reach {reached:.3f}: widen the shape or lower the target "
                         f"(--tau-target)")


def _ways_to_grow(model: ModalModel) -> tuple[Callable, Callable] | None:
    """How ``model`` grows: the band it may reach (Hz; ``f(model, sample_rate)``) and the model with every
    mode below a band (``f(model, band)``); None when it cannot (a beam, an identified model)."""
    if plate_of(model) is not None:
        return drivable_band, grown
    if analytic_plate_of(model) is not None:
        return scene_band, grown_scene
    return None
