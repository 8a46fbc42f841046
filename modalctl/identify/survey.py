"""Identify a structure through a device, from scratch: the thesis's chapter 3, made robust.

1. Every actuator is swept while the vibrometer measures a sparse subset of the points: the
   poles (shared by all FRFs) are found on all of them at once, so a mode that one actuator
   cannot drive (the thesis's mode 18) is still found, and each mode knows which actuators
   drive it.
2. The primary actuator is swept over the full grid; a mode it drives weakly is scanned again
   with the actuator that drives it best. Shapes come from those scans (Eqs 3.9, 3.13).
3. Every actuator's gains follow from its sparse FRFs and the shapes (Eq 3.14, SI units).
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np
from tqdm.auto import tqdm

from modalctl.errors import InputError
from modalctl.io.device import Device
from modalctl.model.files import memory_available
from modalctl.model.modes import Grid, ModalModel, ModelError
from modalctl.model.projection import crosstalk, mass_normalize, orthonormalize_model
from modalctl.model.scenes import ORTHONORMAL_TOLERANCE, resolved_modes
from modalctl.options import SurveyOptions
from modalctl.plugin.manager import pick
from modalctl.threads import serial_blas

from .acquire import measure_frf, measure_frf_into
from .coarse import file_notes
from .estimators import Modes, constants_of, lines_read
from .frf import FRF, H1, Sweep, bending_wavelength, check_spatial_step
from .noise import with_noise_estimate
from .multiref import by_inputs

__all__ = ["Survey", "identify_device", "identify_frf", "scan_subset", "orthogonalize_if_integrated", "mac",
           "to_model", "actuator_gains"]


@dataclass
class Survey:
    """What an identification produced and how.

    Attributes
    ----------
    model : ModalModel
        The identified model on the measured grid.
    poles : Modes
        Every pole found on the sparse FRFs of all actuators (resolved or not).
    drive : ndarray, shape (k, channels)
        RMS modal constant of each resolved mode from each actuator (m/s^2/V).
    shape_actuator : ndarray of int, shape (k,)
        Actuator whose full scan gave each mode's shape.
    crosstalk_before, crosstalk_after : ndarray, shape (k, k)
        Mass-weighted cross-talk of the shapes before and after Gram-Schmidt (Fig 3.11).
    notes : list of str
    seconds : dict
        ``acquisition`` (measurement, or simulation, without the FFTs), ``frf`` (FRF estimation)
        and ``modal`` (poles, shapes, gains): the compute is ``frf + modal``.
    frfs : dict
        ``{"sparse": {actuator: FRF}, "full": {actuator: FRF}}``: the sparse FRFs on the sweep's every
        line, the full scan's on the lines its shapes and gains are fitted on (:func:`~.estimators.lines_read`).
    shape_mac : ndarray, shape (k,)
        MAC of each shape after Gram-Schmidt to itself before (ones when not applied).
    orthogonalized : bool
        Whether Gram-Schmidt was applied (:func:`orthogonalize_if_integrated`).
    """

    model: ModalModel
    poles: Modes
    drive: np.ndarray
    shape_actuator: np.ndarray
    crosstalk_before: np.ndarray
    crosstalk_after: np.ndarray
    notes: list = field(default_factory=list)
    seconds: dict = field(default_factory=dict)
    frfs: dict = field(default_factory=dict)
    shape_mac: np.ndarray = field(default_factory=lambda: np.zeros(0))
    orthogonalized: bool = False


def scan_subset(scan: np.ndarray, step: float) -> np.ndarray:
    """Indices of the scan points (n, d) on a lattice of ``step`` (m) in every direction: along a
    line the first point of each step, on a plate the points whose x and y are both kept."""
    keep = np.ones(len(scan), bool)
    for axis in scan.T:
        values = np.unique(axis)
        chosen = values[np.diff(np.floor((values - values[0]) / step + 1e-9), prepend=-1) > 0]
        keep &= np.isin(axis, chosen)
    return np.flatnonzero(keep)


def identify_device(device: Device, sweep: Sweep, points: np.ndarray, density: float,
                    options: SurveyOptions = SurveyOptions(), wavelength: float | None = None,
                    progress: bool = False, stage: Callable[[str], None] | None = None) -> Survey:
    """Identify the structure behind ``device`` on the scan points ``points``.

    Parameters
    ----------
    device : Device
        Able to scan; configured here at ``sweep.sample_rate``.
    sweep : Sweep
    points : ndarray of int, shape (n,)
        Scan indices of the measurement grid: ordered along a beam; on a plate a rectangular
        grid stored x-fastest, or any scatter (see :meth:`Grid.measured`).
    density : float
        Mass per length of a beam (kg/m) or per area of a plate (kg/m^2): scales the
        mass-normalized shapes, hence the gains.
    options : SurveyOptions
        The identifier, the primary actuator, the sparse grid, averages, Gram-Schmidt.
    wavelength : float, optional
        Shortest bending wavelength in the band (m) for the spatial-step check (Eq 3.15).
    progress, stage : bool, callable or None
        tqdm bars of the steps and sweeps; ``stage(text)`` told each step as it starts, with how long it expects.

    BLAS runs on one thread (:func:`~modalctl.threads.serial_blas`): the identifier's products are
    many and mid-sized, and on two loaded cores OpenBLAS's second thread spins (the plate's survey:
    93 s against 65 s).
    """
    with serial_blas():
        return _identify(device, sweep, points, density, options, wavelength, progress, stage)


def _identify(device: Device, sweep: Sweep, points: np.ndarray, density: float, options: SurveyOptions,
              wavelength: float | None, progress: bool, stage: Callable[[str], None] | None) -> Survey:
    """:func:`identify_device`'s survey."""
    identifier = pick("identifier", options.method)
    primary, sparse, averages = options.primary, options.sparse, options.averages
    caps = device.configure(sweep.sample_rate)
    if not 0 <= primary < caps.channels:
        raise InputError(f"identify: primary actuator {primary}: the device has {caps.channels} "
                         f"(0..{caps.channels - 1})")
    device.activate()
    points = np.asarray(points, int)
    positions = caps.scan_points[points]
    if wavelength is not None:
        check_spatial_step(positions, wavelength)
    few = np.unique(np.r_[np.arange(0, points.size, sparse), points.size - 1])
    steps = _Steps(caps.channels + 3, progress, stage)  # the sparse sweeps, poles, full scan(s), shapes

    t0 = time.perf_counter()
    last = [*(a for a in range(caps.channels) if a != primary), primary]  # the primary's full scan next: one drive
    sparse_frf, stacked = _sparse_scan(steps, device, sweep, last, points[few], averages)
    acquisition = time.perf_counter() - t0

    t0 = time.perf_counter()
    steps.say(f"poles on {few.size * caps.channels} FRFs ({few.size} points x {caps.channels} actuators) x "
              f"{stacked.frequencies.size} lines ({options.method})")
    with _balanced(stacked, sparse_frf) as scales:  # sparse_frf: by actuator (_sparse_scan)
        poles = identifier.identify(stacked, threshold_db=options.threshold_db)
    poles, split = by_inputs(list(sparse_frf.values()), poles, scales)  # read input by input
    good = poles.only_resolved()
    drive = _drives(good, sparse_frf, caps.channels)
    weak = drive[:, primary] < options.weak_drive * drive.max(axis=1)
    chooser = np.where(weak, np.argmax(drive, axis=1), primary)
    compute = time.perf_counter() - t0

    t0 = time.perf_counter()
    # the full scan keeps the lines the shapes and gains are fitted on: the same constants, a fraction of the
    # memory (plate-glass's 7,171 points x 26,224 lines, values, coherence and noise, were 6 GB)
    read = lines_read(sparse_frf[primary].frequencies, good.frequencies, good.damping)
    full_frf = steps.sweeps(device, sweep, sorted(np.unique(chooser), key=lambda a: a != primary), points, averages,
                            "full scan", read)
    acquisition += time.perf_counter() - t0

    t0 = time.perf_counter()
    steps.say(f"shapes of {good.n_modes} modes on {points.size} points, every actuator's gains")
    constants, misfit, resolved = _shape_constants(good, full_frf, chooser, points.size)
    grid = Grid.measured(positions, density)
    notes = [*split, *_notes(poles, good, drive, weak, primary, sweep)]
    shapes_modes = Modes(good.frequencies, good.damping, constants, misfit, resolved, good.method)
    model = to_model(shapes_modes, grid, caps.channels, source=f"identified through {device.url}",
                     sweep={"f_low": sweep.f_low, "f_high": sweep.f_high, "duration": sweep.duration,
                            "sample_rate": sweep.sample_rate, "amplitude": sweep.amplitude},
                     averages=averages)
    order = np.argsort(good.frequencies[resolved])
    model = _with_gains(model, sparse_frf, full_frf, few, points.size)
    before = crosstalk(model.shapes, model.grid.mass)
    model, mac, note = orthogonalize_if_integrated(model, options.orthogonalize)
    notes += [note] if note else []
    after = crosstalk(model.shapes, model.grid.mass)
    compute += time.perf_counter() - t0
    steps.close()
    device.deactivate()
    frf_seconds = sum(f.seconds for f in [*sparse_frf.values(), *full_frf.values()])
    return Survey(model, poles, drive[resolved][order], chooser[resolved][order], before, after, notes,
                  {"acquisition": acquisition - frf_seconds, "frf": frf_seconds, "modal": compute},
                  {"sparse": sparse_frf, "full": full_frf}, mac, bool(model.meta.get("orthonormalized")))


POLES_WORK = 0.25  # the identifier's memory beside the sparse FRFs it reads, as a share of theirs (measured 0.24)


def _sparse_scan(steps: "_Steps", device: Device, sweep: Sweep, actuators: list, points: np.ndarray,
                 averages: int) -> tuple[dict, FRF]:
    """Every one of ``actuators``' FRFs on ``points``, measured in turn into the rows of one FRF (the
    poles' stack, :meth:`FRF.stack`'s layout, by actuator): ``({actuator: its rows}, all of them)``.
    Nothing is copied: plate-glass's 1,435 sparse points x 4 actuators x 26,224 lines are 3.6 GB (the values
    in double precision, coherence and noise in single), and a stacked copy took as much again and 10.7 s."""
    lines = H1(sweep.sample_rate, (sweep.f_low, sweep.f_high), 1).bins(sweep.samples)[0].size
    n, total = points.size, points.size * len(actuators)
    # values, coherence and noise (statistics of a few shots: single precision holds them, 7 digits where the
    # averages give one or two), and the poles' own work beside them (plate-glass: 1.2 GB more on 4.8)
    need, available = total * lines * (24 if averages > 1 else 20) * (1 + POLES_WORK), memory_available()
    if available is not None and need > available:  # np.empty would give it, and the kernel kill the process later
        raise ModelError(f"identify: the sparse FRFs ({total} of {lines} lines) need {need / 2**30:.3g} GiB, more "
                         f"than the {available / 2**30:.3g} GiB of memory available: a lower --f-high, a coarser "
                         f"--resolution or a larger --step")
    stacked = FRF(np.zeros(lines), np.empty((total, lines), complex), np.empty((total, lines), np.float32),
                  np.empty((total, device.capabilities.scan_points.shape[1])), -1, averages, 0.0,
                  np.empty((total, lines), np.float32) if averages > 1 else None)
    into = {a: stacked.rows(slice(i * n, (i + 1) * n)) for i, a in enumerate(sorted(actuators))}  # measured
    # in the order asked, stacked by actuator
    frfs = steps.sweeps(device, sweep, actuators, points, averages, "sparse", into=into)
    first = next(iter(frfs.values()))
    return dict(sorted(frfs.items())), replace(stacked, frequencies=first.frequencies,
                                               averages=min(f.averages for f in frfs.values()))


@contextmanager
def _balanced(stacked: FRF, frfs: dict):
    """Within: ``stacked``'s rows of each actuator (``frfs``' FRFs are views of them) scaled to unit RMS
    as :meth:`FRF.stack` scales them, so that none drowns the others in the poles' fit; after: back to
    their measured values (to rounding). Yields the scales, in ``frfs``' order."""
    scales = FRF.unit_scales(list(frfs.values()))
    for f, c in zip(frfs.values(), scales):
        f.scale_rows(c)
    try:
        yield scales
    finally:
        for f, c in zip(frfs.values(), scales):
            f.scale_rows(1 / c)


class _Steps:
    """The survey's steps told as they start (``stage``) and drawn as a tqdm bar (``progress``),
    each sweep with the time it expects from the point-shots measured so far."""

    def __init__(self, total: int, progress: bool, stage: Callable[[str], None] | None):
        self.stage, self.started, self.progress = stage, False, progress
        self.shots, self.seconds = 0, 0.0  # point-shots measured so far, and in how long (s)
        self.bar = tqdm(total=total, desc="survey", unit="step", disable=not progress, leave=False)

    def say(self, text: str) -> None:
        """A step starts (the one before it is done): one line for ``stage``, the bar's postfix."""
        if self.started:
            self.bar.update(1)
        self.started = True
        self.bar.set_postfix_str(text, refresh=True)
        if self.stage is not None:
            self.stage(text)

    def sweeps(self, device: Device, sweep: Sweep, actuators, points: np.ndarray, averages: int, which: str,
               lines: np.ndarray | None = None, into: dict | None = None) -> dict:
        """``{actuator: FRF}`` of each of ``actuators`` on ``points``, ``averages`` shots each
        (:func:`~.acquire.measure_frf`, keeping ``lines``; or written into ``into[actuator]``'s arrays,
        :func:`~.acquire.measure_frf_into`), each said with the time it expects (at the rate of the
        sweeps before it), and timed."""
        frfs = {}
        for a in actuators:
            shots = points.size * averages
            expect = f", about {shots * self.seconds / self.shots:.0f} s" if self.shots else ""
            self.say(f"FRFs of actuator {a} ({which}): {points.size} points x {averages} shots{expect}")
            start = time.perf_counter()
            frfs[int(a)] = measure_frf(device, sweep, int(a), points, averages, progress=self.progress, lines=lines) \
                if into is None else measure_frf_into(into[a], device, sweep, int(a), points, averages, self.progress)
            self.seconds += time.perf_counter() - start
            self.shots += shots
        return frfs

    def close(self) -> None:
        self.bar.update(1)
        self.bar.close()


def _drives(good: Modes, sparse_frf: dict, channels: int) -> np.ndarray:
    """RMS modal constant of each resolved mode from each actuator on its sparse FRFs, shape
    (k, channels) (m/s^2/V)."""
    drive = np.zeros((good.n_modes, channels))
    for k in range(good.n_modes):
        for a, frf in sparse_frf.items():
            fit = constants_of(frf, good.frequencies, good.damping, k, frequency_check=False)
            drive[k, a] = np.sqrt(np.mean(fit.constants ** 2))
    return drive


def _shape_constants(good: Modes, full_frf: dict, chooser: np.ndarray, n_points: int):
    """Each mode's modal constants on every point, from the full scan of the actuator ``chooser``
    picked for it, with the fit's misfit and whether it resolved the mode."""
    constants = np.zeros((good.n_modes, n_points))
    misfit, resolved = good.misfit.copy(), good.resolved.copy()
    for k in range(good.n_modes):
        fit = constants_of(full_frf[chooser[k]], good.frequencies, good.damping, k)
        constants[k], misfit[k], resolved[k] = fit.constants, fit.misfit, fit.resolved
    return constants, misfit, resolved


def _notes(poles: Modes, good: Modes, drive: np.ndarray, weak: np.ndarray, primary: int, sweep: Sweep) -> list:
    """What the survey tells its reader: the modes the primary actuator drives weakly (and whose
    scan gave their shape), the modes still ringing when the record ends, and the poles left out."""
    notes = [f"mode at {f:.1f} Hz: actuator {primary} drives it at {100 * d[primary] / d.max():.1f}% of "
             f"actuator {int(np.argmax(d))}; shape from actuator {int(np.argmax(d))}"
             for f, d, w in zip(good.frequencies, drive, weak) if w]
    left = [(f, sweep.left_at_end(f, 2 * np.pi * f * z)) for f, z in zip(good.frequencies, good.damping)]
    notes += [f"mode at {f:.1f} Hz still rings at {r:.1e} of its peak when the record ends: its FRF leaks; "
              f"lengthen the tail" for f, r in left if r > 1e-3]
    notes += poles.left_out()
    return notes


def _with_gains(model: ModalModel, sparse_frf: dict, full_frf: dict, few: np.ndarray, n_points: int) -> ModalModel:
    """``model`` with every actuator's gains (every actuator has sparse FRFs): from its full scan
    where there is one, else from its sparse FRFs (the points ``few``)."""
    for a, sparse in sparse_frf.items():
        if a in full_frf:
            model = actuator_gains(model, full_frf[a], np.arange(n_points))
        else:
            model = actuator_gains(model, sparse, few)
    return model


def mac(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Modal assurance criterion of each row of ``a`` with the same row of ``b`` (k, n): shape (k,)."""
    return np.abs(np.sum(a * b, axis=1)) ** 2 / (np.sum(a * a, axis=1) * np.sum(b * b, axis=1))


def orthogonalize_if_integrated(model: ModalModel, wanted: bool = True) -> tuple[ModalModel, np.ndarray, str]:
    """Gram-Schmidt on the shapes only where the grid's weights integrate the modes.

    The test is the one :func:`~modalctl.model.scenes.resolved_modes` makes of a scene's grid:
    the identified (mass-normalized) shapes must be orthonormal on the grid's weights within
    ``ORTHONORMAL_TOLERANCE`` already. Then Gram-Schmidt only removes the noise's small
    cross-talk; on a grid whose weights are no quadrature for the modes (a few uneven points)
    it would turn true shapes into wrong ones, so it is left off with a note.

    Returns
    -------
    model : ModalModel
    mac : ndarray, shape (k,)
        MAC of each shape after to itself before (ones when not applied).
    note : str
        What was done, "" when Gram-Schmidt was applied quietly or not asked for.
    """
    ones = np.ones(model.n_modes)
    if not wanted or model.n_modes < 2:
        return model, ones, ""
    drawn = resolved_modes(model)
    if drawn < model.n_modes:
        talk = np.abs(crosstalk(model.shapes, model.grid.mass) - np.eye(model.n_modes))
        i, j = np.unravel_index(np.argmax(talk), talk.shape)
        return model, ones, (f"Gram-Schmidt not applied: the {model.grid.n} points' weights do not integrate the "
                             f"modes (cross-talk {talk[i, j]:.3f} between the modes at {model.frequencies[i]:.1f} and "
                             f"{model.frequencies[j]:.1f} Hz, above {ORTHONORMAL_TOLERANCE:g}): it would distort the "
                             f"measured shapes")
    ortho = orthonormalize_model(model)
    return ortho, mac(model.shapes, ortho.shapes), ""


def identify_frf(frf, density: float, method: str = SurveyOptions.method, orthogonalize: bool = True,
                 threshold_db: float = SurveyOptions.threshold_db) -> Survey:
    """A model from measured FRFs (e.g. read from UFF 58), on a beam (``density`` in kg/m) or a
    plate (kg/m^2); what was done to the data on the way in is in the notes.

    Parameters
    ----------
    frf : FRF or list of FRF
        One input's FRFs, or several inputs' on the same points (a multi-reference test): the
        poles are found on all at once, each mode's shape comes from the input that drives it
        best, and every input gets its gains. An FRF without a noise estimate (a file without
        coherence) gets one from the scatter between its neighbouring lines
        (:func:`~.noise.with_noise_estimate`).
    orthogonalize : bool
        Gram-Schmidt where the grid integrates the modes (:func:`orthogonalize_if_integrated`).

    BLAS runs on one thread, as in :func:`identify_device`: the answer is then the same whatever
    the machine's cores (on two threads OpenBLAS splits the long sums over the lines in another
    order, and LSCF's ill-conditioned normal equations (:mod:`.lscf`) turn that last bit into
    other poles: the tool-tip file's six modes on two threads, three on one), and the products
    being mid-sized, it is no slower (the tool-tip 2.1-2.5 s -> 1.2-1.4 s, the wheel 2.6 -> 1.6 s).
    """
    with serial_blas():
        return _identify_frf(frf, density, method, orthogonalize, threshold_db)


def _identify_frf(frf, density: float, method: str, orthogonalize: bool, threshold_db: float) -> Survey:
    """:func:`identify_frf`'s work."""
    start = time.perf_counter()
    frfs = [replace(with_noise_estimate(f), actuator=a)  # the inputs given, numbered as given
            for a, f in enumerate(frf if isinstance(frf, (list, tuple)) else [frf])]
    identifier = pick("identifier", method)
    scales = FRF.unit_scales(frfs)  # each input's weight in the poles' fit
    poles = identifier.identify(frfs[0] if len(frfs) == 1 else FRF.stack(frfs, scales), threshold_db=threshold_db)
    poles, split = by_inputs(frfs, poles, scales)  # what the inputs tell apart: close modes, a mode one sees
    grid = Grid.measured(frfs[0].points, density)
    meta = {"source": "identified from measured FRFs", "input_unit": frfs[0].input_unit}
    if len(frfs) == 1:
        model = to_model(poles, grid, 1, **meta)
        drive = np.ones((model.n_modes, 1))
    else:
        good = poles.only_resolved()
        drive = _drives(good, dict(enumerate(frfs)), len(frfs))
        chooser = np.argmax(drive, axis=1)
        constants = np.array([constants_of(frfs[c], good.frequencies, good.damping, k, frequency_check=False).constants
                              for k, c in enumerate(chooser)]).reshape(good.n_modes, -1)
        model = to_model(Modes(good.frequencies, good.damping, constants, good.misfit, good.resolved, good.method),
                         grid, len(frfs), **meta)
        drive = drive[np.argsort(good.frequencies)]
    for f in frfs:
        model = actuator_gains(model, f, np.arange(f.values.shape[0]))
    before = crosstalk(model.shapes, model.grid.mass)
    model, shape_mac, note = orthogonalize_if_integrated(model, orthogonalize)
    noise = [f"noise {frfs[0].noise_source}: median {np.median(frfs[0].noise_std):.2g} {frfs[0].unit}, "
             f"{np.median(frfs[0].noise_std) / np.max(np.abs(frfs[0].values)):.1e} of the largest |H|"] \
        if frfs[0].noise_source else []
    notes = [*frfs[0].notes, *noise, *([note] if note else []),
             *file_notes(frfs, model.frequencies, model.damping, _in_model_order(poles)), *split, *poles.left_out()]
    table = dict(enumerate(frfs))
    return Survey(model, poles, drive, np.zeros(model.n_modes, int), before, crosstalk(model.shapes, model.grid.mass),
                  notes, {"acquisition": 0.0, "frf": 0.0, "modal": time.perf_counter() - start},
                  {"sparse": table, "full": table}, shape_mac, bool(model.meta.get("orthonormalized")))


def beam_wavelength(model_meta: dict, f_high: float) -> float | None:
    """Shortest bending wavelength (m) at ``f_high`` from a scene's metadata, or None."""
    try:
        return bending_wavelength(f_high, model_meta["modulus_Pa"], model_meta["density_kg_m3"],
                                  model_meta["thickness_m"])
    except KeyError:
        return None



def _in_model_order(modes: Modes) -> tuple:
    """The joint fits of the resolved modes (:attr:`Modes.poles`), in the order :func:`to_model` keeps them."""
    good = modes.only_resolved()
    return tuple(good.poles[i] for i in np.argsort(good.frequencies))

def to_model(modes: Modes, grid: Grid, channels: int = 1, **meta) -> ModalModel:
    """A modal model (shapes, no gains yet) from modes whose constants were measured on ``grid``.

    Shapes are scaled to a positive maximum of one (Eq 3.13), then mass-normalized with the
    grid's mass weights. Unresolved modes are left out and listed in ``meta``. The gains of
    each channel come from :func:`actuator_gains`.
    """
    good = modes.only_resolved()
    if good.n_modes == 0:
        raise ModelError("identify: no resolved mode to build a model from")
    peak = np.argmax(np.abs(good.constants), axis=1)
    sign = np.sign(good.constants[np.arange(good.n_modes), peak])
    unit = good.constants / (sign * np.abs(good.constants).max(axis=1))[:, None]  # Eq 3.13
    shapes = mass_normalize(unit, grid.mass)
    order = np.argsort(good.frequencies)
    info = {"identified_by": good.method, "unresolved_hz": modes.frequencies[~modes.resolved].tolist(),
            "misfit": good.misfit[order].tolist(), **meta}
    return ModalModel(grid, good.frequencies[order], good.damping[order], shapes[order],
                      np.zeros((good.n_modes, channels)), meta=info)


def actuator_gains(model: ModalModel, frf: FRF, point_index: np.ndarray) -> ModalModel:
    """Fill one actuator's gains from its FRFs at a few grid points (``point_index`` into the grid).

    With the poles and shapes known, the modal constants at those points are ``phi(p) b``: ``b``
    is their least-squares fit on the shapes at the points (Eq 3.14 with mass-normalized shapes,
    so the gain is in SI units: m/s^2/V per square root of kilogram).
    """
    gains = np.array(model.actuator_gains, copy=True)
    phi = model.shapes[:, point_index]
    for k in range(model.n_modes):
        constants = constants_of(frf, model.frequencies, model.damping, k, frequency_check=False).constants
        gains[k, frf.actuator] = float(phi[k] @ constants / (phi[k] @ phi[k]))
    return replace(model, actuator_gains=gains)
