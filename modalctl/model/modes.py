"""Grids with mass weights and modal models: validation, subsets, and their own ``.npz`` files (no pickle).

A :class:`Grid` is a set of points on the structure (1-D along a beam, 2-D on a plate) with
the mass each point stands for (kg), so that the mass-weighted inner product is
``<f, g> = sum_i m_i f_i g_i``. A :class:`ModalModel` holds the modes on that grid.
"""

from __future__ import annotations

import json
import zipfile
import zlib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from modalctl.errors import InputError
from modalctl.options import VOLTAGE_MIN
from modalctl.outdir import atomic

__all__ = ["ModelError", "Grid", "ModalModel", "quadrature_weights", "check_finite", "drift_cases", "VOLTAGE_LIMIT_KEY"]

FORMAT_VERSION = 1
VOLTAGE_LIMIT_KEY = "voltage_limit_v"  # meta: the actuators' safe drive voltage (V), run's default --voltage-limit

#: The arrays a model file holds (besides ``meta_json``), and the most it may hold in all (bytes):
#: a 2,000 x 2,000 plate with 200 modes is 6.4 GB; a model file beyond that is refused unread.
MODEL_ARRAYS = {"points", "mass", "frequencies", "damping", "shapes", "actuator_gains", "sensor_gains", "labels",
                "rigid_shapes"}
MODEL_BYTES_MAX = 2**33

#: How far from 1 a loaded model's modal masses (``shapes @ diag(mass) @ shapes.T``'s diagonal) may
#: be: a measured model's normalization is approximate, a file of unnormalized shapes is not a model.
MASS_NORMALIZATION_TOLERANCE = 0.2


class ModelError(InputError):
    """Invalid modal data (a model file, a plate's geometry); the message names the field and the offending
    value."""


def check_finite(name: str, array: np.ndarray) -> None:
    """Raise :class:`ModelError` naming ``name`` and the first non-finite entry of ``array``."""
    bad = ~np.isfinite(array)
    if bad.any():
        index = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ModelError(f"{name}: non-finite value {array[index]!r} at index {index}")


def quadrature_weights(x: np.ndarray) -> np.ndarray:
    """Composite Simpson weights (m) for samples at increasing positions ``x``, shape (n,).

    Simpson's rule integrates the smooth products of mode shapes to fourth order, so that
    analytic modes are orthonormal on the grid to about 1e-7 with 1,000 points for 21 modes.
    """
    x = np.asarray(x, dtype=float)
    if x.size < 2:
        raise ModelError(f"grid: need at least 2 points to integrate, got {x.size}")
    if np.any(np.diff(x) <= 0):
        raise ModelError("grid: positions must be strictly increasing")
    from scipy.integrate import simpson  # here: scipy.integrate takes a third of a second to import

    rows = [simpson(np.eye(x.size)[i:i + 256], x=x, axis=1) for i in range(0, x.size, 256)]
    return np.concatenate(rows)


def delaunay_weights(points: np.ndarray) -> np.ndarray:
    """Area (m^2) each of scattered 2-D ``points`` (n, 2) stands for: a third of each Delaunay
    triangle it is a corner of, shape (n,). Exact for fields linear over each triangle."""
    import scipy.spatial

    if len(points) < 3:
        raise ModelError(f"grid: need at least 3 points on a plate, got {len(points)}")
    try:
        tri = scipy.spatial.Delaunay(points)
    except scipy.spatial.QhullError:
        raise ModelError("grid: the plate's points lie on a line") from None
    a, b, c = (points[tri.simplices[:, i]] for i in range(3))
    area = 0.5 * np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
    return np.bincount(tri.simplices.ravel(), np.repeat(area / 3, 3), minlength=len(points))


@dataclass(frozen=True, eq=False)
class Grid:
    """Points on the structure and the mass each stands for.

    Attributes
    ----------
    points : ndarray, shape (n, d)
        Coordinates (m), d = 1 for beams, 2 for plates.
    mass : ndarray, shape (n,)
        Mass weights (kg): ``sum(mass)`` is the mass of the sampled region.
    shape : tuple of int, optional
        ``(nx, ny)`` for a rectangular 2-D grid stored x-fastest, for pictures.
    """

    points: np.ndarray
    mass: np.ndarray
    shape: tuple[int, ...] | None = None

    def __post_init__(self):
        points = np.asarray(self.points, dtype=float)
        if points.ndim == 1:
            points = points[:, None]
        mass = np.asarray(self.mass, dtype=float).ravel()
        if points.shape[0] == 0:
            raise ModelError("grid: empty grid (0 points)")
        if points.ndim != 2 or points.shape[1] not in (1, 2):
            raise ModelError(f"grid.points: expected shape (n, 1) or (n, 2), got {points.shape}")
        if mass.shape != (points.shape[0],):
            raise ModelError(f"grid.mass: expected shape ({points.shape[0]},), got {mass.shape}")
        check_finite("grid.points", points)
        check_finite("grid.mass", mass)
        if np.any(mass < 0):
            raise ModelError(f"grid.mass: negative mass weight {mass.min()!r}")
        if self.shape is not None and int(np.prod(self.shape)) != points.shape[0]:
            raise ModelError(f"grid.shape: {self.shape} does not hold {points.shape[0]} points")
        object.__setattr__(self, "points", points)
        object.__setattr__(self, "mass", mass)

    @classmethod
    def line(cls, start: float, stop: float, n: int, mass_per_length: float) -> "Grid":
        """Uniform 1-D grid of ``n`` points on [start, stop] (m), Simpson mass weights (kg)."""
        if n < 2:
            raise ModelError(f"grid: need at least 2 points, got n={n}")
        x = np.linspace(start, stop, n)
        return cls(x[:, None], mass_per_length * quadrature_weights(x))

    @classmethod
    def rectangle(cls, xlim, ylim, nx: int, ny: int, mass_per_area: float) -> "Grid":
        """Uniform 2-D grid (x fastest) on ``xlim`` x ``ylim`` (m), tensor Simpson weights (kg)."""
        if nx < 2 or ny < 2:
            raise ModelError(f"grid: need at least 2 x 2 points, got {nx} x {ny}")
        x, y = np.linspace(*xlim, nx), np.linspace(*ylim, ny)
        xx, yy = np.meshgrid(x, y)  # shape (ny, nx): x fastest once raveled
        w = np.outer(quadrature_weights(y), quadrature_weights(x))
        return cls(np.column_stack([xx.ravel(), yy.ravel()]), mass_per_area * w.ravel(), (nx, ny))

    @classmethod
    def measured(cls, points: np.ndarray, density: float) -> "Grid":
        """The grid of measured points (m), shape (n, 1) along a line or (n, 2) on a plate.

        Along a line the points must increase (Simpson weights); on a plate they form a full
        rectangular grid stored x-fastest (tensor Simpson weights, ``shape`` set), or else any
        scatter, whose weights are the areas of its Delaunay triangles shared among their corners.
        ``density`` is the mass per length (kg/m) or per area (kg/m^2).
        """
        points = np.asarray(points, float)
        points = points[:, None] if points.ndim == 1 else points
        if points.shape[1] == 1:
            return cls(points, density * quadrature_weights(points[:, 0]))
        x, y = np.unique(points[:, 0]), np.unique(points[:, 1])
        xx, yy = np.meshgrid(x, y)
        if x.size * y.size == len(points) and x.size > 1 and y.size > 1 and np.allclose(
                points, np.column_stack([xx.ravel(), yy.ravel()])):
            w = np.outer(quadrature_weights(y), quadrature_weights(x))
            return cls(points, density * w.ravel(), (x.size, y.size))
        return cls(points, density * delaunay_weights(points))

    @property
    def n(self) -> int:
        """Number of points."""
        return self.points.shape[0]

    @property
    def dim(self) -> int:
        """Spatial dimension (1 or 2)."""
        return self.points.shape[1]

    @property
    def x(self) -> np.ndarray:
        """First coordinate of every point (m), shape (n,)."""
        return self.points[:, 0]

    @property
    def bounds(self) -> np.ndarray:
        """Lower and upper corner (m), shape (2, d)."""
        return np.vstack([self.points.min(axis=0), self.points.max(axis=0)])


def _mode_numbers(labels) -> np.ndarray:
    """Mode numbers as integers; a NaN, an infinity or a fraction is refused, not cast."""
    given = np.asarray(labels)
    if given.dtype.kind in "iub":
        return given.astype(int)
    numbers = np.asarray(given, dtype=float)
    whole = np.isfinite(numbers) & (numbers == np.round(numbers)) & (np.abs(numbers) < 2**53)
    if not np.all(whole):
        i = int(np.argmin(whole.ravel()))
        raise ModelError(f"labels: mode numbers must be whole numbers, got {float(numbers.ravel()[i])!r} at index {i}")
    return numbers.astype(int)


def drift_cases(band: float) -> list[float]:
    """The uniform drifts a design is checked on for a band of +-``band`` (a fraction): both edges of the band
    and its middle points (none for no band). The convex planner's robust margin holds on them, and a
    cluster's law must stay stable on them (:mod:`modalctl.loops.cluster`)."""
    return [] if not band else [-band, -band / 2, band / 2, band]


@dataclass(frozen=True, eq=False)
class ModalModel:
    """Modes of a structure sampled on a grid.

    Attributes
    ----------
    grid : Grid
    frequencies : ndarray, shape (k,)
        Resonance frequencies (Hz), positive.
    damping : ndarray, shape (k,)
        Damping ratios, in (0, 1).
    shapes : ndarray, shape (k, n)
        Mass-normalized mode shapes (1/sqrt(kg)): ``shapes @ diag(mass) @ shapes.T = I``.
    actuator_gains : ndarray, shape (k, a)
        Modal gain of each actuator on each mode (sqrt(kg) m / (s^2 V)): eta'' + 2 zeta w eta' + w^2 eta = B v.
    sensor_gains : ndarray, shape (k, s)
        Sensor s reads ``sum_k sensor_gains[k, s] * eta_k'`` (m/s).
    labels : ndarray of int, shape (k,)
        Mode numbers as the user knows them (e.g. the thesis's numbering).
    rigid_shapes : ndarray, shape (r, n)
        Mass-normalized zero-frequency (rigid-body) modes; they cannot be driven at resonance
        and are kept apart so that decomposition can report what they carry.
    meta : dict
        JSON-serializable description (name, source, actuator and sensor names...).
    """

    grid: Grid
    frequencies: np.ndarray
    damping: np.ndarray
    shapes: np.ndarray
    actuator_gains: np.ndarray | None = None
    sensor_gains: np.ndarray | None = None
    labels: np.ndarray | None = None
    rigid_shapes: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        f = np.atleast_1d(np.asarray(self.frequencies, dtype=float))
        z = np.atleast_1d(np.asarray(self.damping, dtype=float))
        k, n = f.size, self.grid.n
        if k == 0:
            raise ModelError("frequencies: a modal model needs at least one mode")
        shapes = np.asarray(self.shapes, dtype=float)
        checks = [("frequencies", f, (k,)), ("damping", z, (k,)), ("shapes", shapes, (k, n))]
        gains = {}
        for name in ("actuator_gains", "sensor_gains"):
            value = getattr(self, name)
            value = np.zeros((k, 0)) if value is None else np.asarray(value, dtype=float)
            if value.ndim == 1:
                value = value[:, None]
            gains[name] = value
            checks.append((name, value, (k, value.shape[1] if value.ndim == 2 else -1)))
        labels = np.arange(1, k + 1) if self.labels is None else _mode_numbers(self.labels)
        checks.append(("labels", labels, (k,)))
        rigid = np.zeros((0, n)) if self.rigid_shapes is None else np.atleast_2d(np.asarray(self.rigid_shapes, float))
        checks.append(("rigid_shapes", rigid, (rigid.shape[0], n)))
        for name, value, expected in checks:
            if value.shape != expected:
                raise ModelError(f"{name}: expected shape {expected} for {k} modes on {n} points, got {value.shape}")
            check_finite(name, value)
        if np.any(f <= 0):
            i = int(np.argmax(f <= 0))
            raise ModelError(f"frequencies: must be positive (Hz), got {f[i]!r} for mode {labels[i]}")
        if np.any((z <= 0) | (z >= 1)):
            i = int(np.argmax((z <= 0) | (z >= 1)))
            raise ModelError(f"damping: must lie in (0, 1), got {z[i]!r} for mode {labels[i]}")
        if len(set(labels.tolist())) != k:
            raise ModelError(f"labels: mode numbers must be unique, got {labels.tolist()}")
        if not isinstance(self.meta, dict):
            raise ModelError(f"meta: must be a dict (a JSON object), got {type(self.meta).__name__}")
        try:
            json.dumps(self.meta)
        except TypeError as exc:
            raise ModelError(f"meta: must be JSON-serializable ({exc})") from None
        limit = self.meta.get(VOLTAGE_LIMIT_KEY)
        if limit is not None and not (isinstance(limit, (int, float)) and not isinstance(limit, bool)
                                      and np.isfinite(limit) and limit >= VOLTAGE_MIN):
            raise ModelError(f"meta.{VOLTAGE_LIMIT_KEY}: the actuators' safe voltage must be a finite number of "
                             f"volts, at least {VOLTAGE_MIN:g} V, got {limit!r}")
        for name, value in [("frequencies", f), ("damping", z), ("shapes", shapes), ("labels", labels),
                            ("rigid_shapes", rigid), *gains.items()]:
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    @property
    def voltage_limit(self) -> float | None:
        """The actuators' safe drive voltage (V, peak, either sign) the model carries in ``meta``
        (``voltage_limit_v``: a piezo patch's depolarization field times its thickness, see
        :meth:`modalctl.model.structures.Piezo.safe_voltage`), or None when it does not say
        (an identified model, a file written before it was kept)."""
        limit = self.meta.get(VOLTAGE_LIMIT_KEY)
        return None if limit is None else float(limit)

    @property
    def n_modes(self) -> int:
        """Number of (elastic) modes."""
        return self.frequencies.size

    @property
    def omega(self) -> np.ndarray:
        """Angular resonance frequencies (rad/s), shape (k,)."""
        return 2 * np.pi * self.frequencies

    def select(self, modes) -> "ModalModel":
        """Return the model restricted to ``modes`` (positional indices, in the given order)."""
        idx = np.asarray(modes, dtype=int).ravel()
        if idx.size == 0:
            raise ModelError("select: no modes selected")
        if idx.min() < 0 or idx.max() >= self.n_modes:
            raise ModelError(f"select: mode index out of range 0..{self.n_modes - 1}: {idx.tolist()}")
        return replace(self, frequencies=self.frequencies[idx], damping=self.damping[idx],
                       shapes=self.shapes[idx], actuator_gains=self.actuator_gains[idx],
                       sensor_gains=self.sensor_gains[idx], labels=self.labels[idx])

    def drifted(self, shift: float) -> "ModalModel":
        """The model with every resonance moved by the fraction ``shift`` (0.01: 1% higher): the structure
        a uniform drift (temperature, a clamp's stiffness) makes, as the HIL's ``--drift`` does without its
        spread (:func:`modalctl.hil.scenario.perturb`)."""
        return replace(self, frequencies=self.frequencies * (1 + shift))

    def index_of(self, labels) -> np.ndarray:
        """Positional indices of the modes numbered ``labels``."""
        where = {int(l): i for i, l in enumerate(self.labels)}
        missing = [int(l) for l in np.atleast_1d(labels) if int(l) not in where]
        if missing:
            raise ModelError(f"labels: no mode numbered {missing}; the model has {self.labels.tolist()}")
        return np.array([where[int(l)] for l in np.atleast_1d(labels)], dtype=int)

    # ----------------------------------------------------------------- files
    def save(self, path) -> Path:
        """Write the model to one ``.npz`` file (atomically: a temporary file beside it, then renamed):
        arrays plus a JSON metadata entry (no pickle), stored, not deflated: float64 shapes deflate
        by some 6 % only, for 1.5 s of the tablet panel's 254 modes (0.2 s stored)."""
        path = Path(path)
        if path.suffix != ".npz":
            path = path.with_suffix(".npz")
        path.parent.mkdir(parents=True, exist_ok=True)  # as the output options promise (made if absent)
        header = {"format": "modalctl.ModalModel", "version": FORMAT_VERSION, "meta": self.meta,
                  "grid_shape": list(self.grid.shape) if self.grid.shape else None}
        with atomic(path) as temporary:  # a full disk leaves the file that was there whole
            np.savez(
                temporary, meta_json=np.array(json.dumps(header)), points=self.grid.points, mass=self.grid.mass,
                frequencies=self.frequencies, damping=self.damping, shapes=self.shapes,
                actuator_gains=self.actuator_gains, sensor_gains=self.sensor_gains, labels=self.labels,
                rigid_shapes=self.rigid_shapes)
        return path

    @classmethod
    def load(cls, path) -> "ModalModel":
        """Read a model written by :meth:`save`."""
        path = Path(path)
        if not path.is_file():
            raise ModelError(f"model file: no such file {str(path)!r}")
        from .files import check_npz

        name = str(path)
        check_npz(path, f"model file: {name!r}", MODEL_BYTES_MAX)  # sizes from the headers, before any array
        try:
            with np.load(path, allow_pickle=False) as data:
                arrays = {key: data[key] for key in data.files}
        except (ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error) as exc:  # not a zip, truncated, corrupted
            raise ModelError(f"model file: {name!r} is not a modalctl .npz model ({exc})") from None
        try:
            header = json.loads(str(arrays.pop("meta_json")))
        except KeyError:
            raise ModelError(f"model file: {name!r} has no meta_json entry") from None
        except (ValueError, RecursionError) as exc:  # not JSON, or nested past Python's limit (a crafted file)
            raise ModelError(f"model file: {name!r}: meta_json is not JSON ({type(exc).__name__}: "
                             f"{str(exc)[:200]})") from None
        if not isinstance(header, dict) or header.get("format") != "modalctl.ModalModel" \
                or not isinstance(header.get("version", 0), int) or header.get("version", 0) > FORMAT_VERSION:
            found = header if not isinstance(header, dict) else (header.get("format"), header.get("version"))
            raise ModelError(f"model file: {name!r}: unsupported format {found!r}")
        unknown = set(arrays) - MODEL_ARRAYS
        missing = {"points", "mass", "frequencies", "damping", "shapes"} - set(arrays)
        if unknown or missing:
            raise ModelError(f"model file: {name!r}: " + "; ".join(
                part for part in (f"unknown entries {sorted(unknown)}" if unknown else "",
                                  f"missing entries {sorted(missing)}" if missing else "") if part))
        try:
            shape = tuple(int(s) for s in header["grid_shape"]) if header.get("grid_shape") else None
        except (TypeError, ValueError):
            raise ModelError(f"model file: {name!r}: grid_shape {header['grid_shape']!r} is not a shape") from None
        for key, value in arrays.items():
            if value.dtype.kind not in "biuf" or value.ndim == 0:
                raise ModelError(f"model file: {name!r}: entry {key!r} holds {value.dtype} of shape {value.shape}, "
                                 "not an array of real numbers")
        try:
            grid = Grid(arrays.pop("points"), arrays.pop("mass"), shape)
            model = cls(grid=grid, meta=header.get("meta", {}), **arrays)
        except ModelError as exc:
            raise ModelError(f"model file: {name!r}: {exc}") from None
        _check_distinct(grid, name)
        _check_normalized(model, name)
        return model


def _check_distinct(grid: Grid, name: str) -> None:
    """Refuse a loaded grid where two points share their coordinates: each point stands for its
    own mass, and a field sampled twice at one place is two fields."""
    unique, first, counts = np.unique(grid.points, axis=0, return_index=True, return_counts=True)
    if len(unique) != grid.n:
        twice = int(np.flatnonzero(counts > 1)[0])
        raise ModelError(f"model file: {name!r}: grid points share coordinates "
                         f"{tuple(float(c) for c in unique[twice])} (point {int(first[twice])} and "
                         f"{int(counts[twice]) - 1} more): a grid's points are distinct")


def _check_normalized(model: ModalModel, name: str) -> None:
    """Refuse a loaded model whose shapes are not mass-normalized on its grid (within
    :data:`MASS_NORMALIZATION_TOLERANCE`): coefficients and tau would be meaningless."""
    masses = np.einsum("kn,n,kn->k", model.shapes, model.grid.mass, model.shapes)
    off = np.abs(masses - 1.0) > MASS_NORMALIZATION_TOLERANCE
    if np.any(off):
        i = int(np.argmax(np.abs(masses - 1.0)))
        raise ModelError(f"model file: {name!r}: mode {model.labels[i]}'s modal mass on the grid is {masses[i]:.3g}, "
                         f"not 1: the shapes must be mass-normalized (sum_i m_i phi_k(x_i)^2 = 1)")
