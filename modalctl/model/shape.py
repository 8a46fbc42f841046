"""What a shape generator plugin returns and how its typed parameters are parsed.

A shape generator is any object with ``name``, ``summary``, ``params`` (a tuple of
:class:`Param`) and ``generate(grid, **params) -> Shape``; plugins return them from the
``modalctl_shapes`` hook (see :mod:`modalctl.plugin.spec`).
"""

from __future__ import annotations

from dataclasses import dataclass
from abc import ABC, abstractmethod
from typing import Any

import numpy as np

from modalctl.errors import InputError
from modalctl.units import UnitError, parse_point, parse_quantity

from .modes import Grid, ModelError

__all__ = ["Shape", "Param", "ShapeGenerator", "ParamError", "parse_params", "generated", "checked_target",
           "tukey_window", "PEAK_MIN", "PEAK_MAX"]

#: The peak velocity (m/s) a target may ask: below, under any vibrometer's noise and where the modal sums
#: underflow (1e-300 m/s planned a NaN tau); above, no surface moves (1e300 m/s overflowed them)
PEAK_MIN, PEAK_MAX = 1e-9, 1e3


class ParamError(InputError):
    """A shape parameter that is unknown, missing or malformed."""


@dataclass(frozen=True, eq=False)
class Shape:
    """A target velocity field at the focus time and the zone where it is meant to be felt.

    Attributes
    ----------
    values : ndarray, shape (n,)
        Velocity on the grid (m/s).
    target_mask : ndarray of bool, shape (n,)
        True where the stimulus is meant to be felt (margin checks look outside it).
    """

    values: np.ndarray
    target_mask: np.ndarray

    def __post_init__(self):
        values = np.asarray(self.values, dtype=float).ravel()
        mask = np.asarray(self.target_mask, dtype=bool).ravel()
        if values.shape != mask.shape:
            raise ModelError(f"shape.target_mask: {mask.shape} points for a field of {values.shape}")
        if not np.all(np.isfinite(values)):
            raise ModelError("shape.values: non-finite values in the target field")
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "target_mask", mask)


@dataclass(frozen=True)
class Param:
    """A typed shape parameter.

    Attributes
    ----------
    name : str
    unit : str
        Dimension accepted by :func:`modalctl.units.parse_quantity` (``"m"``, ``"m/s"``, ``"1"``),
        or ``"text"`` for a string passed through, or ``"any"`` for a Python object.
    default : Any
        Value used when the parameter is not given (SI units).
    doc : str
    point : bool
        True for a position that takes one coordinate per grid dimension (``"24mm,10mm"``).
    required : bool
        True when the parameter has no default.
    """

    name: str
    unit: str
    default: Any = None
    doc: str = ""
    point: bool = False
    required: bool = False

    def parse(self, raw):
        """Convert a raw value (text with units or a number) to SI."""
        if self.unit in ("text", "any"):
            return raw
        if self.point:
            return parse_point(raw, self.unit, self.name)
        return parse_quantity(raw, self.unit, self.name)


class ShapeGenerator(ABC):
    """A shape generator, as plugins provide them (hook ``modalctl_shapes``): a subclass names
    itself, lists its typed parameters and draws its field.

    Attributes
    ----------
    name, summary : str
    params : tuple of Param
        What ``generate`` accepts, with units and defaults (parsed by :func:`parse_params`).
    """

    name: str
    summary: str
    params: tuple[Param, ...] = ()

    @abstractmethod
    def generate(self, grid: Grid, **params) -> Shape:
        """Target field and mask on ``grid`` for SI parameter values."""


def generated(generator: ShapeGenerator, grid: Grid, raw: dict) -> Shape:
    """``generator``'s target on ``grid`` for the raw parameters ``raw`` (:func:`parse_params`), checked as a
    target a user asks for: not zero on every grid point, its peak within [:data:`PEAK_MIN`, :data:`PEAK_MAX`]
    m/s. Raises :class:`ParamError` saying which."""
    return checked_target(generator.generate(grid, **parse_params(generator, raw)), f"shape {generator.name!r}")


def checked_target(shape: Shape, name: str = "shape") -> Shape:
    """``shape``, a target asked for (:func:`generated`'s, or one built by hand and handed to
    :func:`~modalctl.plan.decompose.decompose`), or a :class:`ParamError` saying ``name``'s target is zero on every
    grid point or has its peak outside [:data:`PEAK_MIN`, :data:`PEAK_MAX`] m/s."""
    peak = float(np.abs(shape.values).max(initial=0.0))
    if peak == 0.0:
        raise ParamError(f"{name}: the target is zero on every grid point (an amplitude of zero, a width far below "
                         f"the grid's spacing, or parts that cancel): nothing to focus")
    if not PEAK_MIN <= peak <= PEAK_MAX:
        raise ParamError(f"{name}: the target's peak velocity {peak:.3g} m/s lies outside [{PEAK_MIN:g}, {PEAK_MAX:g}] "
                         f"m/s")
    return shape


def parse_params(generator: ShapeGenerator, raw: dict) -> dict:
    """Check and convert raw parameter values for ``generator`` into SI values, defaults filled in.

    Raises :class:`ParamError` listing the accepted parameters when a name is unknown, a
    required one is missing, or a value does not parse.
    """
    known = {p.name: p for p in generator.params}
    unknown = sorted(set(raw) - set(known))
    accepted = ", ".join(f"{p.name} [{p.unit}]" for p in generator.params)
    if unknown:
        raise ParamError(f"shape {generator.name!r}: unknown parameter {unknown[0]!r}; accepted: {accepted}")
    values = {}
    for name, p in known.items():
        if name in raw:
            try:
                values[name] = p.parse(raw[name])
            except UnitError as exc:
                raise ParamError(f"shape {generator.name!r}: {exc}") from None
        elif p.required:
            raise ParamError(f"shape {generator.name!r}: parameter {name!r} is required; accepted: {accepted}")
        else:
            values[name] = p.default
    return values


def tukey_window(grid: Grid, taper: float) -> np.ndarray:
    """Tukey window over the grid's extent, zero at the edges, shape (n,).

    ``taper`` is the fraction of each axis spent in the cosine ramps (0: no window). On a 2-D
    grid the window is the product of one window per axis.
    """
    if not 0 <= taper <= 1:
        raise ParamError(f"taper: must lie in [0, 1], got {taper!r}")
    window = np.ones(grid.n)
    lo, hi = grid.bounds
    for axis in range(grid.dim):
        u = (grid.points[:, axis] - lo[axis]) / (hi[axis] - lo[axis])
        window *= _tukey01(u, taper)
    return window


def _tukey01(u: np.ndarray, taper: float) -> np.ndarray:
    """Tukey window at relative positions ``u`` in [0, 1] (the definition of scipy's ``tukey``)."""
    if taper == 0:
        return np.ones_like(u)
    edge = np.minimum(u, 1 - u)  # distance to the nearer end
    return np.where(edge < taper / 2, 0.5 * (1 - np.cos(2 * np.pi * edge / taper)), 1.0)
