"""A measured space-time field on file: small, fast to write, read back as measured.

A plate's scan is tens of millions of samples (8591 points x 5240 instants on the panel), but the
field a structure makes lives in a few tens of modes: written as it is (float32, zlib) it took
160 MB and 4-9 s a run. Here it is stored as what it is, a low-rank part and what that part
leaves:

    field = basis @ coefficients + step * residual

``basis`` (n, r) and ``coefficients`` (r, nt) are the field's leading singular vectors (a
randomized range finder, two passes over the field in blocks), ``residual`` (n, nt) is the rest
rounded to ``step`` and packed in the fewest bits that hold it (8, 16 or 32). Nothing of the
measurement is dropped but what lies under ``step / 2`` (plus float32's rounding of the sums,
``2^-20`` of the peak). ``step`` is ``2^-16`` of the field's peak (a 17-bit vibrometer), or, where
the modes leave more than that (the measurement's noise), an eighth of what they leave (its RMS):
rounding then adds ``1/768`` to the noise's variance, and never coarser than ``2^-10`` of the peak.
So a noise-free field's residual rounds to zero and compresses to nothing, and a noisy one keeps
its noise in about five bits a sample. Files are ``.npz`` (no pickle) with a JSON header naming
every array and its unit.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .modes import ModelError

__all__ = ["FieldRecord", "write_field_record", "read_field_record", "RESOLUTION", "FORMAT"]

FORMAT = "modalctl.FieldRecord"
VERSION = 1
RESOLUTION = 2.0 ** -16  # the residual's finest step, relative to the field's peak
NOISE_STEPS = 8  # steps per RMS of what the modes leave: rounding adds 1 / (12 x 8^2) to its variance
COARSEST = 2.0 ** -10  # the residual's coarsest step, relative to the field's peak
RANK_MAX = 64  # columns of the range finder: a scene's modes and then some
_BLOCK = 512  # grid points per block of each pass


@dataclass(frozen=True, eq=False)
class FieldRecord:
    """A field measured on a grid over time.

    Attributes
    ----------
    times : ndarray, shape (nt,)
        s.
    points : ndarray, shape (n, d)
        m.
    field : ndarray, shape (n, nt)
        Velocity, m/s (float32).
    step : float
        What the file kept of it: every sample within ``step / 2`` (m/s).
    rank : int
        Columns of the low-rank part on file.
    extra : dict of str to ndarray
        The other arrays written beside the field (a run's target, voltages, sensors...), as written.
    """

    times: np.ndarray
    points: np.ndarray
    field: np.ndarray
    step: float = 0.0
    rank: int = 0
    extra: dict = field(default_factory=dict)


def _low_rank(field: np.ndarray, rank: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, float]:
    """An orthonormal basis (n, k) of the field's range, its coefficients (k, nt), k <= ``rank``
    (Halko, Martinsson and Tropp's range finder), and the RMS of what they leave."""
    n, nt = field.shape
    probe = np.random.default_rng(seed).standard_normal((nt, rank)).astype(np.float32)
    sketch = np.empty((n, rank), np.float32)
    for start in range(0, n, _BLOCK):
        sketch[start:start + _BLOCK] = field[start:start + _BLOCK] @ probe
    basis = np.linalg.qr(sketch)[0]
    coefficients = np.zeros((rank, nt), np.float32)
    energy = 0.0
    for start in range(0, n, _BLOCK):
        block = field[start:start + _BLOCK]
        coefficients += basis[start:start + _BLOCK].T @ block
        energy += float(np.einsum("ij,ij->", block, block, dtype=np.float64))
    u, s, vt = np.linalg.svd(coefficients, full_matrices=False)
    keep = s > s[0] * 1e-7 if s.size and s[0] > 0 else np.zeros(s.size, bool)  # float32's own resolution
    left = max(0.0, energy - float(np.sum(s[keep].astype(np.float64) ** 2)))  # Pythagoras: the basis is orthonormal
    return (basis @ u[:, keep]).astype(np.float32), (s[keep, None] * vt[keep]).astype(np.float32), \
        float(np.sqrt(left / field.size))


def _residual(field: np.ndarray, basis: np.ndarray, coefficients: np.ndarray, step: float) -> np.ndarray:
    """What the low-rank part leaves, rounded to ``step``, in the fewest bits that hold it (8, 16, 32)."""
    out = np.empty(field.shape, np.int32)
    for start in range(0, field.shape[0], _BLOCK):
        rows = slice(start, start + _BLOCK)
        out[rows] = np.rint((field[rows] - basis[rows] @ coefficients) / step)
    low, high = (int(out.min()), int(out.max())) if out.size else (0, 0)
    for kind in (np.int8, np.int16):
        if np.iinfo(kind).min <= low and high <= np.iinfo(kind).max:
            return out.astype(kind)
    return out


def write_field_record(path, times, points, values, resolution: float = RESOLUTION, extra: dict | None = None) -> Path:
    """Write the field ``values`` (n, nt) m/s measured at ``times`` (nt,) s on ``points`` (n, d) m to
    ``path`` (``.npz``), every sample kept within half a step (``resolution`` times its peak, or
    an eighth of the RMS of what its modes leave: see the module's notes), and the arrays of
    ``extra`` as they are (their names prefixed ``extra_`` on file). Returns the path."""
    field = np.ascontiguousarray(values, np.float32)
    times, points = np.asarray(times, float), np.asarray(points, float).reshape(len(field), -1)
    if field.ndim != 2 or field.shape[1] != times.size:
        raise ModelError(f"field record: field {field.shape} does not match {times.size} instants")
    if not np.all(np.isfinite(field)):
        raise ModelError("field record: the field holds NaN or infinite samples")
    peak = float(np.max(np.abs(field))) if field.size else 0.0
    basis, coefficients, left = _low_rank(field, min(RANK_MAX, *field.shape)) if peak > 0 else (
        np.zeros((field.shape[0], 0), np.float32), np.zeros((0, field.shape[1]), np.float32), 0.0)
    step = max(peak * resolution, min(left / NOISE_STEPS, peak * COARSEST)) if peak > 0 else 1.0
    residual = _residual(field, basis, coefficients, step)
    header = {"format": FORMAT, "version": VERSION, "step_m_per_s": step, "resolution": resolution,
              "field": "basis @ coefficients + step * residual", "units": {
                  "times": "s", "points": "m", "basis": "1", "coefficients": "m/s", "residual": "step"}}
    arrays = {"header_json": np.array(json.dumps(header)), "times": times, "points": points, "basis": basis,
              "coefficients": coefficients, "residual": residual,
              **{f"extra_{name}": np.asarray(value) for name, value in (extra or {}).items()}}
    path = Path(path)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as archive:  # np.load reads it
        for name, array in arrays.items():
            with archive.open(f"{name}.npy", "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asanyarray(array), allow_pickle=False)
    return path


def read_field_record(path) -> FieldRecord:
    """The field a :func:`write_field_record` file holds, as measured to within its step."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            header = json.loads(str(data["header_json"]))
            if header.get("format") != FORMAT:
                raise ModelError(f"field record: {str(path)!r} is not a field record ({header.get('format')!r})")
            basis, coefficients, residual = data["basis"], data["coefficients"], data["residual"]
            times, points = data["times"], data["points"]
            extra = {key[len("extra_"):]: data[key] for key in data.files if key.startswith("extra_")}
    except ModelError:
        raise
    except (ValueError, OSError, KeyError, EOFError, zipfile.BadZipFile, json.JSONDecodeError) as exc:
        raise ModelError(f"field record: cannot read {str(path)!r} ({exc})") from None
    step = float(header["step_m_per_s"])
    values = (basis @ coefficients + np.float32(step) * residual).astype(np.float32)
    return FieldRecord(times, points, values, step, basis.shape[1], extra)
