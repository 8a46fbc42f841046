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

A model that can grow also grows to the band the convex plan's drive reaches (:func:`drive_band`: its
hats near T_F, every ``ConvexOptions.hat``, carry it up to their Nyquist frequency): a drive reaching
past the model's highest mode excites modes the margin program does not see. plate-glass's 21 modes
below 12.0 kHz, its 30 mm Gaussian at (20, 10) mm under the default closed loop: the 20 us hats put
2.6e-2 of the drive's energy above 1.5 times its highest mode, and a truth with twice its modes
measured margin 0.88 (modes at 20.3-20.4 kHz rang at the focus). Grown to 25 kHz (48 modes), over
three noise seeds: untouched 0.472 on its own truth, 0.488 on one with twice its modes; a finger
landing at 20 ms given back 119%, margin 0.487 / 0.494 (the 21 modes with hats coarsened to their
band instead, :func:`modalctl.plan.convex_basis.hat_spacing`: 64%, 0.556 / 0.587). A model that
cannot grow, or would grow past :data:`DRIVE_MODES_MAX` modes, keeps its hats within its band that way.
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

from .convex_basis import hat_spacing
from .reduction import ReductionError

__all__ = ["Growth", "model_for", "reach", "drive_band", "GROWTH", "DRIVE_MODES_MAX"]

GROWTH = 1.5  # each step's band over the last's: about 1.5x the modes (Weyl: count grows with the band)
# The most modes a model grows to for its drive's band: past it the hats are coarsened to the model's band
# instead where they reach far past it (hat_spacing). The tablet panel (254 modes to 19.9 kHz) would grow
# to about 320 for 25 kHz, and its 30 mm bump's command ran past 5 minutes instead of 56 s; plate-glass (21
# to 12.0 kHz) grows to 48, panel-rounded (22 to 11.8 kHz) to 53, in about a second once solved.
DRIVE_MODES_MAX = 128


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
    if options.modes != "auto" or ways is None:
        return model, None
    band_of, grown_to = ways
    limit = band_of(model, options.sample_rate)
    first = float(model.frequencies.max())
    if options.tau_min is not None and before < options.tau_min:
        bigger, growth = _grown_for_shape(model, shape, options, say, ways, limit, before)
    else:
        bigger, growth = model, None
    drive = min(drive_band(options), limit)
    top = float(bigger.frequencies.max())
    if top >= drive * (1 - 1e-6):
        return bigger, growth
    if bigger.n_modes * drive / top > DRIVE_MODES_MAX:  # a plate's modes grow with the band (Weyl)
        if say is not None:
            spacing = hat_spacing(options.convex.hat, top)
            say(f"its {bigger.n_modes} modes stop at {top:.0f} Hz, below the {drive:.0f} Hz the plan's drive would "
                f"reach: about {bigger.n_modes * drive / top:.0f} modes to grow to, more than {DRIVE_MODES_MAX}; "
                + (f"the plan's hats are spaced {spacing * 1e6:.1f} us instead (its band's Nyquist interval)"
                   if spacing > options.convex.hat else "not grown (within 1.5x of its band, the drive's hats "
                   "put little above it)"))
        return bigger, growth
    why = (f"its {bigger.n_modes} modes stop at {top:.0f} Hz, and the plan's drive reaches {drive:.0f} Hz (its hats "
           f"every {options.convex.hat * 1e6:g} us near T_F): modes the margin would not see")
    if growth is not None:
        why = f"{growth.reason}; then {why}"
    if say is not None:
        say(f"{why}: solving the plate again to {drive:.0f} Hz")
    bigger = grown_to(model, drive)
    return bigger, Growth(first, float(bigger.frequencies.max()), model.n_modes, bigger.n_modes, before,
                          reach(bigger, shape), limit, why)


def drive_band(options: PlanOptions) -> float:
    """The highest frequency the plan's drive carries (Hz): the convex planner's hats near T_F, every
    ``options.convex.hat``, interpolate the voltage linearly between samples that far apart, up to their
    Nyquist frequency ``1 / (2 hat)`` (25 kHz for 20 us); 0 for another planner (its drive is the kept
    modes' carriers)."""
    name = options.planner if isinstance(options.planner, str) else getattr(options.planner, "name", None)
    return 1 / (2 * options.convex.hat) if name == "convex" else 0.0


def _grown_for_shape(model: ModalModel, shape: Shape, options: PlanOptions, say, ways, limit: float,
                     before: float) -> tuple[ModalModel, Growth]:
    """``model`` grown a :data:`GROWTH` step at a time until its modes reach ``options.tau_min`` on
    ``shape`` (``before``: what they reach now); :class:`ReductionError` at ``limit`` (Hz)."""
    _, grown_to = ways
    first = float(model.frequencies.max())
    why = (f"its {model.n_modes} modes below {first:.0f} Hz reach tau {before:.3f} on the shape, below the target "
           f"{options.tau_min:g}")
    band, bigger, reached = first, model, before
    while band < limit * (1 - 1e-6):
        band = min(limit, band * GROWTH)
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
