"""A measured space-time field on file: small, fast to write, read back as measured.

A plate's scan is a hundred million samples (8591 points x 11659 instants on the panel), but the
field a structure makes lives in a few tens of modes: written as it is (float32, zlib) it took
160 MB and 4-9 s a run. Here it is stored as what it is, a low-rank part, what that part leaves,
and the noise a simulated vibrometer added, told by its key:

    field = basis @ coefficients + step * residual [+ noise]

``basis`` (n, r) and ``coefficients`` (r, nt) span the field's range, trimmed to the directions
the field uses: the caller's basis (the model's mode shapes on the grid, orthonormalized: one pass
over the field) and, where what it leaves would make the step coarser than the finest (an RMS over
eight finest steps), a randomized range finder's directions of what it leaves (Halko, Martinsson
and Tropp: a round of 64 in two more passes, at most 4 rounds). A direction is kept where it
carries more than four times what white noise of what the round leaves could (the square of that
noise's largest singular value, sigma (sqrt(n) + sqrt(nt))): modes the basis lacks (a structure
the model does not hold, as every real one), not noise. Without a basis the first round is the
range finder on the whole field. The threshold is where the step would leave the finest: below it
the step is the finest anyway (what is left, if anything, kept in the residual), and the one
pass's measure of what is left (the field's energy less its coefficients', float32 sums) is not
much finer.
``residual`` (n, nt) is the rest rounded to ``step`` and packed in the fewest bits that hold it
(8, 16 or 32). ``step`` is ``2^-16`` of the field's peak (a 17-bit vibrometer), or, where the basis
and the range finder leave more than eight of those (the measurement's noise: no direction of it
carries more than white noise does), an eighth of what they leave (its RMS): rounding then adds
``1/768`` to the noise's variance, and never coarser than ``2^-10`` of the peak.

What the record guarantees, every sample within ``step / 2`` of the field measured (plus float32's
rounding of the sums, ``2^-20`` of the peak) whatever it holds:

* A noise-free field (a simulation without ``--snr``): the finest step; the residual rounds to
  zero and compresses to nothing (the panel's 8591 x 11659: 6.4 MB, the basis and coefficients),
  whether the basis holds every mode (truth = model: one pass) or not (another scene's truth: a
  round of the range finder finds the rest). Only a field beyond what 4 rounds of 64 find (more
  modes than that, or so many weak ones that each carries less than white noise of their energy
  would) is stored as a noisy one, at a step from what is left.
* A simulated vibrometer's noisy field, its noise described (``noise``, a
  :class:`~modalctl.model.noise_stream.NoiseStream` from :meth:`Device.scan_noise_stream
  <modalctl.io.device.Device.scan_noise_stream>`): the noise is taken away before the split and
  regenerated on reading (its generator, version, key and sigma in the header, its samples and
  points as arrays), so the field is stored as a noise-free one, at the finest step and the same
  size; the field read back is the scan, within the step. A generator or version this modalctl
  does not have is refused (a :class:`ModelError`), never silently read without its noise. A
  description that does not match the samples costs size, not accuracy: the residual keeps
  what it missed.
* A simulator's field with the modes it made it of (``modes``, :meth:`Device.scan_modes
  <modalctl.io.device.Device.scan_modes>`): stored as that description (no pass over the field, the
  residual zero), once blocks of points drawn across it are within the step of it; the guarantee then
  rests on the device's description, checked on those blocks only (the header says
  ``made_by_device``).
* A real vibrometer's field (no description: its noise is in its samples): white noise has no
  structure, so the residual keeps it in about five bits a sample (a step of an eighth of its RMS)
  and zlib gets little of that: about 60-95 MB for the panel's hundred million samples at 40 dB.
  The modes its basis lacks are found as in a noise-free field (a round, and one more that finds
  only noise): they do not coarsen the step.
* An empty field (no points or no instants) writes and reads, its step 1.

Files are ``.npz`` (no pickle) with a JSON header naming every array and its unit; version 1
files (no noise) read too. Writing runs the passes on two threads of its own with BLAS on one
(OpenBLAS's threads spin for a core on a busy machine).
"""

from __future__ import annotations

import json
import zipfile
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from modalctl.threads import serial_blas

from .modes import ModelError
from .noise_stream import GENERATOR, NoiseStream
from .noise_stream import VERSION as NOISE_VERSION

__all__ = ["FieldRecord", "write_field_record", "read_field_record", "RESOLUTION", "FORMAT"]

FORMAT = "modalctl.FieldRecord"
VERSION = 2  # 2: the noise a simulated vibrometer added, described (version 1 files read too)
RESOLUTION = 2.0 ** -16  # the residual's finest step, relative to the field's peak
NOISE_STEPS = 8  # steps per RMS of what the modes leave: rounding adds 1 / (12 x 8^2) to its variance
COARSEST = 2.0 ** -10  # the residual's coarsest step, relative to the field's peak
STORED_BYTES = 2**20  # floating-point arrays over this are stored, not deflated (see _member)
RANK_MAX = 64  # columns of the range finder: a scene's modes and then some
ROUNDS = 4  # of the range finder on what the basis leaves: up to 4 x 64 directions the basis lacks
_BLOCK = 256  # grid points per block of each pass (12 MB of the panel's field: L3 holds it)
CHECKED = 4  # blocks of a simulator's field checked against the modes it was made of


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
    noise : NoiseStream or None
        The noise the file described rather than stored (added back to ``field``).
    """

    times: np.ndarray
    points: np.ndarray
    field: np.ndarray
    step: float = 0.0
    rank: int = 0
    extra: dict = field(default_factory=dict)
    noise: NoiseStream | None = None


def _low_rank(values: np.ndarray, noise: NoiseStream | None, basis: np.ndarray | None, resolution: float):
    """The part of ``values`` (n, nt) to store (the field less its known noise: a copy, or ``values``
    itself), an orthonormal basis (n, k) of its range, its coefficients (k, nt), the RMS of what
    they leave, and the measured field's peak.

    The basis is ``basis``'s (one pass over the field: the noise, the peak, the energy, the
    coefficients) and, while what it leaves would make the step coarser than the finest (an RMS
    over ``NOISE_STEPS`` finest steps), the range finder's (Halko, Martinsson and Tropp's) of what
    is left: a round of two passes, at most ``ROUNDS``, keeping the directions that carry more than
    white noise of what is left could (:func:`_beyond`). Without ``basis`` the first round is the
    range finder on the whole field. What is left then is noise, or modes beyond the rounds."""
    n, nt = values.shape
    given = np.zeros((n, 0), np.float32) if basis is None else _orthonormal(_columns(basis, n, np.float32))
    field, peak, energy, coefficients = _prepared(values, noise, given)
    coefficients = np.zeros((given.shape[1], nt), np.float32) if coefficients is None else coefficients
    left = max(0.0, energy - float(np.sum(np.square(coefficients, dtype=np.float64))))  # Pythagoras
    finest = field.size * (NOISE_STEPS * peak * resolution) ** 2  # what leaves the step its finest
    rng = np.random.default_rng(0)
    for _ in range(ROUNDS):
        if left <= finest or given.shape[1] >= min(n, nt):
            break
        found, more, power = _beyond(field, given, coefficients, (left, energy), rng)
        if not found.shape[1]:  # what is left is noise, as far as the range finder can tell
            break
        given, coefficients, left = np.hstack([given, found]), np.vstack([coefficients, more]), max(0.0, left - power)
    coefficients64 = coefficients.astype(np.float64)
    power, directions = np.linalg.eigh(coefficients64 @ coefficients64.T)  # the coefficients' SVD, from k x k
    keep = power > power.max(initial=0.0) * 1e-14  # singular values within float32's resolution of the largest
    left = max(0.0, energy - float(np.sum(power[keep])))  # Pythagoras: the basis is orthonormal
    directions = directions[:, keep][:, ::-1]  # the strongest first
    return field, (given @ directions.astype(np.float32)), (directions.T @ coefficients64).astype(np.float32), \
        float(np.sqrt(left / max(field.size, 1))), peak


def _beyond(field: np.ndarray, basis: np.ndarray, coefficients: np.ndarray, energies: tuple, rng):
    """A round of the range finder on what ``basis @ coefficients`` leaves of ``field`` (``energies``:
    its energy, and the field's): directions (n, m) orthonormal and orthogonal to ``basis``, their
    coefficients (m, nt) and the energy they carry, keeping only those that carry more than four
    times what the strongest direction of white noise of the energy the round leaves could (its
    largest singular value, sigma (sqrt(n) + sqrt(nt)), twice over: structure, not noise) and more
    than 10^-12 of the field's energy (float32's rounding of it, not structure). Two passes: the
    sketch, the coefficients."""
    n, nt = field.shape
    probe = rng.standard_normal((nt, min(RANK_MAX, n, nt))).astype(np.float32)

    def sketch(rows: slice):
        rest = field[rows] if not basis.shape[1] else field[rows] - basis[rows] @ coefficients
        return rest @ probe, 0.0

    sketched = _sum_of_halves(sketch, n, vertical=True)[0].astype(np.float64)
    basis64 = basis.astype(np.float64)
    for _ in range(2):  # twice: what the first projection's rounding left of the basis taken away too
        sketched -= basis64 @ (basis64.T @ sketched)
    found = _orthonormal(sketched)
    more = _sum_of_halves(lambda rows: (found[rows].T @ field[rows], 0.0), n)[0].astype(np.float64)
    power, directions = np.linalg.eigh(more @ more.T)
    left, energy = energies
    rest = max(0.0, left - float(np.sum(power)))  # what the round leaves: noise, or modes beyond it
    keep = power > max(4 * rest / field.size * (np.sqrt(n) + np.sqrt(nt)) ** 2, 1e-12 * energy)
    directions = directions[:, keep]
    return found @ directions.astype(np.float32), (directions.T @ more).astype(np.float32), float(np.sum(power[keep]))


def _columns(array, n: int, dtype) -> np.ndarray:
    """``array`` as ``n`` rows (a column when it is one-dimensional): a 2-D array as it is, even empty."""
    array = np.asarray(array, dtype)
    return array if array.ndim == 2 else array.reshape(n, -1)


def _orthonormal(columns: np.ndarray) -> np.ndarray:
    """An orthonormal basis (n, k) float32 of the range of ``columns`` (n, m), k <= m: from the
    m x m Gram matrix in float64 (its eigenvectors, then Cholesky once more to square what they
    left), directions under 10^-6 of the strongest dropped. (LAPACK's QR of the tall matrix took
    0.2-1.2 s on the panel's 8591 x 53, by how busy the machine was.)"""
    tall = columns.astype(np.float64)
    power, vectors = np.linalg.eigh(tall.T @ tall)
    keep = power > power.max(initial=0.0) * 1e-12
    tall = tall @ (vectors[:, keep] / np.sqrt(power[keep]))
    if tall.shape[1]:
        tall = np.linalg.solve(np.linalg.cholesky(tall.T @ tall), tall.T).T  # tall R^-1, R^T R its Gram
    return np.ascontiguousarray(tall, np.float32)


def _sum_of_halves(work, n: int, vertical: bool = False):
    """``work(rows)`` -> (array, number) on the blocks of ``_BLOCK`` points of two halves of the
    ``n`` points, one thread each (NumPy lets go of the GIL; the caller keeps BLAS on one thread:
    OpenBLAS's own threads spin waiting for a core on a busy machine); the arrays summed, or
    stacked (``vertical``), and the numbers summed."""
    half = -(-n // 2 // _BLOCK) * _BLOCK

    def part(first: int, last: int):
        arrays, total = [], 0.0
        for start in range(first, last, _BLOCK):
            array, number = work(slice(start, min(start + _BLOCK, last)))
            total += number
            if array is not None:
                arrays = arrays + [array] if vertical or not arrays else [arrays[0] + array]
        return arrays, total

    with ThreadPoolExecutor(2) as pool:
        parts = list(pool.map(part, (0, half), (min(half, n), n)))
    arrays = [array for found, _ in parts for array in found]
    total = sum(number for _, number in parts)
    return (np.vstack(arrays) if vertical else sum(arrays[1:], arrays[0])) if arrays else None, total


def _prepared(values: np.ndarray, noise: NoiseStream | None, basis: np.ndarray):
    """``values`` less ``noise`` (a new array; ``values`` itself without noise), the peak of
    ``values``, the energy (sum of squares) of what is left, and its coefficients on ``basis``
    (None without points): one pass, a block of points at a time, on two threads."""
    field = values if noise is None else np.empty_like(values)
    peaks = []

    def block(rows: slice):
        if noise is not None:
            field[rows] = values[rows]
            noise.add_to(field[rows], rows.start, sign=-1)
        peaks.extend([float(values[rows].max(initial=0)), -float(values[rows].min(initial=0))])  # (holds the GIL)
        return basis[rows].T @ field[rows], float(np.einsum("ij,ij->", field[rows], field[rows], dtype=np.float64))

    coefficients, energy = _sum_of_halves(block, len(values))
    peak = float(np.max(peaks)) if peaks else 0.0
    if not np.isfinite(peak):  # max and min propagate NaN
        raise ValueError("field record: the field holds NaN or infinite samples")
    return field, peak, energy, coefficients


def _residual(field: np.ndarray, basis: np.ndarray, coefficients: np.ndarray, step: float) -> np.ndarray:
    """What the low-rank part leaves, rounded to ``step``, in the fewest bits that hold it (8, 16,
    32): made in 8 bits on two threads (zeros that are not written cost nothing), the blocks that
    need more made again once it is widened."""
    out, scale = np.zeros(field.shape, np.int8), np.float32(1 / step)
    wide = []

    def block(rows: slice, out: np.ndarray = out):
        left = np.matmul(basis[rows], coefficients)
        np.subtract(field[rows], left, out=left)
        low, high = float(left.min()), float(left.max())
        if max(-low, high) < 0.5 * step:  # rounds to zero: a modal field's residual
            return None, 0.0
        left *= scale
        np.rint(left, out=left)
        kind = next((k for k in (np.int8, np.int16) if np.iinfo(k).min <= low * scale
                     and high * scale <= np.iinfo(k).max), np.int32)
        if np.iinfo(kind).max > np.iinfo(out.dtype).max:
            wide.append((rows, kind))  # (list.append holds the GIL)
        else:
            out[rows] = left
        return None, 0.0

    _sum_of_halves(block, len(field))
    if wide:
        out = out.astype(max((kind for _, kind in wide), key=lambda k: np.iinfo(k).max))
        for rows, _ in wide:
            block(rows, out)
    return out


def write_field_record(path, times, points, values, extra: dict | None = None, noise: NoiseStream | None = None,
                       basis: np.ndarray | None = None, modes=None) -> Path:
    """Write the field ``values`` (n, nt) m/s measured at ``times`` (nt,) s on ``points`` (n, d) m to
    ``path`` (``.npz``), every sample kept within half a step (:data:`RESOLUTION` of its peak, or
    an eighth of the RMS of the noise its modes leave: see the module's notes), and the arrays of
    ``extra`` as they are (their names prefixed ``extra_`` on file). Returns the path.

    ``noise``: the noise the scan added, as its generator makes it again (a simulated vibrometer's,
    :meth:`modalctl.io.device.Device.scan_noise_stream`): stored by its description, not its
    samples. ``basis`` (n, k): shapes the field lives in (the model's modes on the grid), used
    instead of finding them (one pass over the field instead of three); where what they leave
    would coarsen the step, the range finder finds what they lack (two passes a round), and what
    is left after that is kept too, in the residual. ``modes`` ``(shapes (n, k), velocities (k,
    nt))``: the field less its noise as a simulator made it (:meth:`Device.scan_modes
    <modalctl.io.device.Device.scan_modes>`), trusted as the noise's key is and stored as it is,
    without the passes, once blocks of points drawn across the field are found within half the finest
    step of it (else as without it; see :func:`_as_made`). A plain ValueError when these do not fit
    one another or the field is not finite: what modalctl made, so a bug, not bad input (issue 39)."""
    field = np.ascontiguousarray(values, np.float32)
    times, points = np.asarray(times, float), _columns(points, len(field), float)
    if field.ndim != 2 or field.shape[1] != times.size:
        raise ValueError(f"field record: field {field.shape} does not match {times.size} instants")
    if basis is not None and np.shape(basis)[0] != field.shape[0]:
        raise ValueError(f"field record: a basis of {np.shape(basis)[0]} points for a field on {field.shape[0]}")
    if noise is not None and noise.shape != field.shape:
        raise ValueError(f"field record: noise {noise.shape} for a field {field.shape}")
    if noise is not None and (noise.generator, noise.version) != (GENERATOR, NOISE_VERSION):
        raise ValueError(f"field record: noise from generator {noise.generator!r} version {noise.version}; this "
                         f"modalctl makes {GENERATOR!r} version {NOISE_VERSION} only")
    with serial_blas():  # small products but for the passes, which run on two threads of their own
        given = None if modes is None else _as_made(field, noise, modes, RESOLUTION)
        if given is not None:
            basis, coefficients, step = given
            residual = np.zeros(field.shape, np.int8)  # as the device made it: its description, spot-checked
        else:
            stored, basis, coefficients, left, peak = _low_rank(field, noise, basis, RESOLUTION)
            step = max(peak * RESOLUTION, min(left / NOISE_STEPS, peak * COARSEST)) if peak > 0 else 1.0
            residual = _residual(stored, basis, coefficients, step) if field.size else np.zeros(field.shape, np.int8)
    header = {"format": FORMAT, "version": VERSION, "step_m_per_s": step, "resolution": RESOLUTION,
              "field": "basis @ coefficients + step * residual" + (" + noise" if noise else ""),
              "made_by_device": given is not None,  # basis and coefficients the device's own, spot-checked
              "noise": None if noise is None else {
                  "generator": noise.generator, "version": noise.version, "key": list(noise.key),
                  "sigma_m_per_s": noise.sigma, "samples": "noise_samples", "rows": "noise_rows"},
              "units": {"times": "s", "points": "m", "basis": "1", "coefficients": "m/s", "residual": "step",
                        **({"noise_samples": "sample", "noise_rows": "grid point"} if noise else {})}}
    arrays = {"header_json": np.array(json.dumps(header)), "times": times, "points": points, "basis": basis,
              "coefficients": coefficients, "residual": residual,
              **({"noise_samples": noise.samples, "noise_rows": noise.rows} if noise else {}),
              **{f"extra_{name}": np.asarray(value) for name, value in (extra or {}).items()}}
    path = Path(path)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as archive:  # np.load reads it
        for name, array in arrays.items():
            array = np.asanyarray(array)
            with archive.open(_member(f"{name}.npy", array), "w", force_zip64=True) as member:
                np.lib.format.write_array(member, array, allow_pickle=False)
    return path


def _member(name: str, array: np.ndarray) -> str | zipfile.ZipInfo:
    """Where ``array`` goes in the archive: deflated (the archive's default) unless it is floating point and
    over :data:`STORED_BYTES`, which is stored as it is: measured floats deflate by 4-10%, at a second per 32 MB
    (the tablet's basis: 1.1 s for 7%), where the residual's steps, mostly zero, deflate 230-fold (0.7 s for
    the tablet's 294 MB) and a grid's coordinates or a record's instants, small, by 30-90%."""
    if array.dtype.kind not in "fc" or array.nbytes < STORED_BYTES:
        return name
    info = zipfile.ZipInfo(name)
    info.compress_type = zipfile.ZIP_STORED
    return info


def _as_made(field: np.ndarray, noise: NoiseStream | None, modes, resolution: float):
    """``(basis, coefficients, step)`` of a field a device says it made as ``shapes @ velocities`` (+
    ``noise``), the finest step. The description is the device's own (a simulator's), trusted as its
    noise's key is, and checked on :data:`CHECKED` blocks of :data:`_BLOCK` points drawn across the
    field (noise taken away): a description wrong on many points is caught, one wrong on a few
    unchecked points is not. None (the passes instead) when a checked sample is off by more than
    half the step, the field is empty, or the modes are as many as the points or instants (no smaller)."""
    shapes, velocity = (np.ascontiguousarray(a, np.float32) for a in modes)
    n, nt = field.shape
    if shapes.shape[0] != n or velocity.shape != (shapes.shape[1], nt):
        raise ValueError(f"field record: modes {shapes.shape} x {velocity.shape} for a field {field.shape}")
    if shapes.shape[1] >= min(n, nt):
        return None
    peak = max(float(field.max(initial=0.0)), -float(field.min(initial=0.0)))
    if not np.isfinite(peak):
        raise ValueError("field record: the field holds NaN or infinite samples")
    if not (n and nt and peak > 0):
        return None
    step = peak * resolution
    for first in np.unique(np.random.default_rng(n).integers(0, max(n - _BLOCK, 0) + 1, CHECKED)):
        rows = slice(first, min(first + _BLOCK, n))
        left = field[rows] - shapes[rows] @ velocity
        if noise is not None:
            noise.add_to(left, first, sign=-1)
        if not np.abs(left).max() <= step / 2:
            return None
    return shapes, velocity, step


def read_field_record(path) -> FieldRecord:
    """The field a :func:`write_field_record` file holds, as measured to within its step (its noise
    regenerated when the file describes it)."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            header = json.loads(str(data["header_json"]))
            if not isinstance(header, dict) or header.get("format") != FORMAT:
                raise ModelError(f"field record: {str(path)!r} is not a field record "
                                 f"({header.get('format') if isinstance(header, dict) else type(header).__name__!r})")
            if header.get("version") not in (1, VERSION):
                raise ModelError(f"field record: {str(path)!r} is version {header.get('version')!r}; this "
                                 f"modalctl reads versions 1 to {VERSION}")
            basis, coefficients, residual = data["basis"], data["coefficients"], data["residual"]
            times, points = data["times"], data["points"]
            noise = _noise(header.get("noise"), data, path)
            extra = {key[len("extra_"):]: data[key] for key in data.files if key.startswith("extra_")}
        step = float(header["step_m_per_s"])
        values = np.matmul(basis, coefficients, dtype=np.float32)
        if residual.shape != values.shape:
            raise ModelError(f"field record: {str(path)!r}: residual {residual.shape} for a field {values.shape}")
        for start in range(0, values.shape[0], _BLOCK):  # a block at a time: no temporary as large as the field
            rows = slice(start, start + _BLOCK)
            values[rows] += np.float32(step) * residual[rows]
        if noise is not None:
            if noise.shape != values.shape:
                raise ModelError(f"field record: {str(path)!r}: noise {noise.shape} for a field {values.shape}")
            noise.add_to(values)
    except ModelError:
        raise
    except (ValueError, OSError, KeyError, TypeError, AttributeError, EOFError, zipfile.BadZipFile,
            RecursionError) as exc:  # RecursionError: a header nested past Python's limit
        raise ModelError(f"field record: cannot read {str(path)!r} ({exc})") from None
    return FieldRecord(times, points, values, step, basis.shape[1], extra, noise)


def _noise(described, data, path) -> NoiseStream | None:
    """The noise stream a record's header describes, or None; a generator this modalctl does not
    have is refused."""
    if described is None:
        return None
    if not isinstance(described, dict):
        raise ModelError(f"field record: {str(path)!r} describes its noise as {described!r}, not as its generator, "
                         f"version, key and sigma")
    generator, version = described.get("generator"), described.get("version")
    if (generator, version) != (GENERATOR, NOISE_VERSION):
        raise ModelError(f"field record: {str(path)!r} stores its noise as generator {generator!r} version "
                         f"{version!r}; this modalctl regenerates {GENERATOR!r} version {NOISE_VERSION} only, "
                         f"so it cannot give back the field measured")
    return NoiseStream(tuple(described["key"]), float(described["sigma_m_per_s"]), data[described["samples"]],
                       data[described["rows"]])
