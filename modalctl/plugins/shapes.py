"""First-party shape generators: sinc, bump, square, trapezoid, gaussian, sum, array.

Width convention (thesis section 4.2.1): a pulse's ``width`` is its full width at 30% of
its amplitude, and its target zone (where the stimulus is meant to be felt) is where the
pulse profile reaches 30% of the amplitude. On a 2-D grid pulses are round (distance to the
centre), the square is square. An optional Tukey window (``taper``, fraction of each axis)
brings the field to zero at the edges of the structure, as the thesis did so that the
field is compatible with the supports.
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from modalctl.model.modes import Grid
from modalctl.model.shape import Param, ParamError, Shape, ShapeGenerator, parse_params, tukey_window
from modalctl.plugin.spec import hookimpl

#: Relative level that defines pulse width and target zone (the thesis's 30%).
LEVEL = 0.3

_COMMON = (
    Param("amplitude", "m/s", 0.04, "peak velocity at the focus (m/s)"),
    Param("center", "m", (0.0,), "focus position, one coordinate per grid axis: 24mm or 24mm,10mm", point=True),
    Param("taper", "1", 0.2, "Tukey window taper fraction per axis, 0 for none"),
)


def _distance(grid: Grid, center, metric: str) -> np.ndarray:
    center = tuple(center)
    if len(center) == 1 and grid.dim == 2:
        center = (center[0], 0.0)
    if len(center) != grid.dim:
        raise ParamError(f"center: {len(center)} coordinates given for a {grid.dim}-D grid")
    low, high = grid.bounds
    outside = [i for i, c in enumerate(center) if not low[i] <= c <= high[i]]
    if outside:
        span = ", ".join(f"{1e3 * lo:g} to {1e3 * hi:g} mm" for lo, hi in zip(low, high))
        raise ParamError(f"center: {', '.join(f'{1e3 * c:g} mm' for c in center)} lies off the structure "
                         f"(its grid spans {span})")
    delta = np.abs(grid.points - np.asarray(center))
    if grid.mass[np.argmin((delta**2).sum(axis=1))] <= 0:  # within the bounds, in a hole or past a rounded corner
        raise ParamError(f"center: {', '.join(f'{1e3 * c:g} mm' for c in center)} lies off the structure: in a "
                         "hole, on its rim or past it (the nearest grid point carries no mass)")
    return delta.max(axis=1) if metric == "chebyshev" else np.sqrt((delta**2).sum(axis=1))


def _sinc(r, width):
    return np.sinc(3 * r / (2 * width))  # np.sinc(u) = sin(pi u)/(pi u); 0.3 at r = width/2


_BUMP_V = 1 - 1 / (1 - np.log(LEVEL))  # (r/R)^2 where the bump is at 30%


def _bump(r, width):
    radius = (width / 2) / np.sqrt(_BUMP_V)
    v = np.minimum((r / radius) ** 2, 1.0)
    with np.errstate(divide="ignore", over="ignore"):
        return np.where(v < 1, np.exp(1 - 1 / (1 - v)), 0.0)


def _square(r, width):
    return (r <= width / 2).astype(float)


def _gaussian(r, width):
    sigma = (width / 2) / np.sqrt(2 * np.log(1 / LEVEL))
    return np.exp(-(r**2) / (2 * sigma**2))


def _trapezoid(r, width, top):
    top = width / 2 if top is None else top
    if not 0 <= top < width:
        raise ParamError(f"trapezoid: top ({top!r} m) must lie in [0, width) with width {width!r} m")
    return np.clip((width / 2 - r) / ((width - top) / 2), 0.0, 1.0)


@dataclass(frozen=True)
class Pulse(ShapeGenerator):
    """A pulse given by a profile of the distance to its centre (peak 1 at the centre)."""

    name: str
    summary: str
    profile: Callable[..., np.ndarray]
    width_doc: str
    extra: tuple[Param, ...] = ()
    metric: str = "euclidean"
    params: tuple[Param, ...] = field(init=False)

    def __post_init__(self):
        width = Param("width", "m", doc=self.width_doc, required=True)
        object.__setattr__(self, "params", (width, *self.extra, *_COMMON))

    def generate(self, grid: Grid, *, width, amplitude, center, taper, **extra) -> Shape:
        if width <= 0:
            raise ParamError(f"{self.name}: width must be positive, got {width!r} m")
        profile = self.profile(_distance(grid, center, self.metric), width, **extra)
        window = tukey_window(grid, taper)
        _say_if_the_taper_moves_it(grid, profile, window, self.name, taper)
        return Shape(amplitude * profile * window, (profile >= LEVEL) & (window > 0))


class TaperWarning(UserWarning):
    """The taper (a window that brings the field to zero at the edges) changed the pulse asked for."""


TAPER_TOLERANCE = 0.05  # of the peak: a taper that lowers the pulse more than this is said


def _say_if_the_taper_moves_it(grid: Grid, profile: np.ndarray, window: np.ndarray, name: str, taper: float) -> None:
    """Warn when the taper lowers the pulse's peak or moves it off its grid point: the target is then
    the tapered shape, not the one asked for (issue 26: a bump 20 mm at 48 mm on a clamped beam
    peaked at 43.4 mm, and the run measured tau against it without a word)."""
    asked, tapered = int(np.argmax(np.abs(profile))), int(np.argmax(np.abs(profile * window)))
    kept = abs(profile[tapered] * window[tapered]) / max(abs(profile[asked]), 1e-300)
    if tapered == asked and kept >= 1 - TAPER_TOLERANCE:
        return
    where = grid.points[tapered] - grid.points[asked]
    moved = float(np.linalg.norm(where)) * 1e3
    warnings.warn(f"{name}: the taper ({taper:g} of each axis) moves the pulse's peak by {moved:.1f} mm and "
                  f"keeps {100 * kept:.0f}% of it; the target is the tapered shape (--param taper=0 keeps "
                  "the pulse as asked)", TaperWarning, stacklevel=3)


SINC = Pulse("sinc", "cardinal sine A sinc(3 (x - xc) / (2 width)) (thesis Eq 4.1)", _sinc,
             "full width at 30% of the amplitude (m)")
BUMP = Pulse("bump", "smooth compact bump (A/e) exp(-1/(1 - (r/R)^2)) (thesis Eq 4.3)", _bump,
             "full width at 30% of the amplitude (m); the support is 1.35 times wider")
SQUARE = Pulse("square", "flat pulse of the given width (thesis Eq 4.4)", _square, "full width (m)",
               metric="chebyshev")
GAUSSIAN = Pulse("gaussian", "Gaussian pulse", _gaussian, "full width at 30% of the amplitude (m)")
TRAPEZOID = Pulse("trapezoid", "flat top with linear flanks (thesis chapter 5)", _trapezoid,
                  "full width at the base (m)",
                  extra=(Param("top", "m", None, "width of the flat top (m), less than width; default width/2"),))


class SumShape(ShapeGenerator):
    """Several shapes at once (several foci): the sum of their fields, the union of their zones."""

    name = "sum"
    summary = "sum of shapes, e.g. parts='sinc(width=18mm,center=-24mm)+bump(width=25mm,center=24mm)'"
    params = (Param("parts", "any", required=True, doc="shapes to add: text 'name(k=v,...)+name(...)' or a list of "
                                          "(name, {param: value}) pairs"),)

    def generate(self, grid: Grid, *, parts) -> Shape:
        from modalctl.plugin.manager import get_shape

        items = parse_parts(parts) if isinstance(parts, str) else list(parts)
        if not items:
            raise ParamError("sum: no parts given")
        values, mask = np.zeros(grid.n), np.zeros(grid.n, bool)
        for name, raw in items:
            generator = get_shape(name)
            shape = generator.generate(grid, **parse_params(generator, raw))
            values, mask = values + shape.values, mask | shape.target_mask
        return Shape(values, mask)


_PART = re.compile(r"\s*([A-Za-z_][\w-]*)\s*\(([^()]*)\)\s*")


def parse_parts(text: str) -> list[tuple[str, dict]]:
    """Parse ``"sinc(width=18mm,center=-24mm)+bump(width=25mm)"`` into (name, raw params) pairs.

    A value may hold commas (a 2-D centre ``center=24mm,10mm``): a token without ``=``
    continues the value before it.
    """
    items = []
    for chunk in _split_top(text):
        match = _PART.fullmatch(chunk)
        if not match:
            raise ParamError(f"sum: cannot read part {chunk!r}; write name(key=value,...)")
        raw: dict[str, str] = {}
        key = None
        for token in filter(None, (t.strip() for t in match.group(2).split(","))):
            if "=" in token:
                key, value = (s.strip() for s in token.split("=", 1))
                raw[key] = value
            elif key is None:
                raise ParamError(f"sum: value {token!r} without a name in {chunk!r}")
            else:
                raw[key] += "," + token
        items.append((match.group(1), raw))
    return items


def _split_top(text: str) -> list[str]:
    parts, depth, start = [], 0, 0
    for i, ch in enumerate(text):
        depth += ch == "("
        depth -= ch == ")"
        if ch == "+" and depth == 0:
            parts.append(text[start:i])
            start = i + 1
    parts.append(text[start:])
    return [p for p in parts if p.strip()]


class ArrayShape(ShapeGenerator):
    """A field given point by point: an array, or a ``.npy`` / ``.csv`` file with one value per grid point."""

    name = "array"
    summary = "field from an array or a .npy/.csv file (m/s), one value per grid point"
    params = (Param("values", "any", required=True, doc="array (n,) in m/s, or a path to a .npy or .csv file"),
              Param("threshold", "1", LEVEL, "target zone: |value| at least this fraction of the peak"),
              Param("taper", "1", 0.0, "Tukey window taper fraction per axis, 0 for none"))

    def generate(self, grid: Grid, *, values, threshold, taper) -> Shape:
        array = _load_values(values)
        if array.shape != (grid.n,):
            raise ParamError(f"array: values have shape {array.shape}, the grid has {grid.n} points")
        if not np.all(np.isfinite(array)) or not np.any(array):
            raise ParamError("array: values must be finite and not all zero")
        field_ = array * tukey_window(grid, taper)
        return Shape(field_, np.abs(field_) >= threshold * np.abs(field_).max())


def _load_values(values) -> np.ndarray:
    if isinstance(values, (str, Path)):
        path = Path(values)
        if not path.is_file():
            raise ParamError(f"array: no such file {str(path)!r}")
        if path.suffix == ".npy":
            from modalctl.model.files import read_npy
            from modalctl.model.modes import ModelError

            try:
                return read_npy(path, "array").astype(float).ravel()
            except ModelError as exc:
                raise ParamError(str(exc)) from None
        try:
            return np.loadtxt(path, delimiter=",", ndmin=1, comments="#").astype(float).ravel()
        except ValueError as exc:
            raise ParamError(f"array: cannot read {str(path)!r}: {exc}") from None
    return np.asarray(values, dtype=float).ravel()


@hookimpl
def modalctl_shapes():
    """The first-party shape generators."""
    return [SINC, BUMP, SQUARE, TRAPEZOID, GAUSSIAN, SumShape(), ArrayShape()]
