"""Correct a plan's voltages near the focus so that the margin holds on the whole model.

The envelope optimizer (:mod:`modalctl.plan.kappa`) holds the margin on the kept modes' references;
near T_F their envelopes turn fast, and fast turns also ring the modes the plan left out and leak
among the kept ones (more kept modes than actuators cannot keep them apart). This step adds a
correction to every actuator's voltage, sample by sample, over a window around T_F, found by
L-BFGS-B (scipy) on the exact plant of every mode of the model:

* minimize the p-norm of the off-target field from the window's start to the end of the shot
  (a smooth stand-in for its largest value, sharpened from ``p = 16`` to ``256``),
* holding the field at T_F where it is (a quadratic penalty),
* each voltage within its limit (bounds; without a limit, within the plan's own peak).

The gradient is exact: the plant is linear and time-invariant, so the transpose of
"voltages -> modal velocities" is the same plant run backwards in time.
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import minimize
from tqdm.auto import tqdm

from modalctl.model.modes import ModalModel
from modalctl.model.propagate import Plant

__all__ = ["Refinement", "Search", "refine"]

#: p-norm continuation (p a power of two) and the off-target grid points watched (None: all):
#: a sample of the grid while the search moves far, every point to finish (between sampled
#: points the field would be pushed up)
STAGES = ((16, 128), (64, 128), (256, None))
PENALTY = 1e3  # weight of the focus field's change, in units of the focus peak squared


@dataclass
class Refinement:
    """A voltage correction and what it reached.

    Attributes
    ----------
    correction : ndarray, shape (a, w)
        Volts added to each actuator from sample ``start`` on.
    start : int
        First corrected DAC sample.
    ratio, ratio_before : float
        Whole-model margin ratio, every sample from ``start`` to the end, with and without it.
    focus_change : float
        Largest change of the field at T_F, relative to its peak.
    seconds : float
    evaluations : int
        Plant runs (forward and adjoint pairs).
    """

    correction: np.ndarray
    start: int
    ratio: float
    ratio_before: float
    focus_change: float
    seconds: float
    evaluations: int


@dataclass(frozen=True)
class Search:
    """Where and how long the correction is searched.

    Attributes
    ----------
    before, after : float
        Correction window around T_F (s): where the envelopes' fast turns are.
    iterations : int
        L-BFGS-B iterations at most per sharpening of the p-norm.
    progress : bool
        A progress bar of the iterations, with the ratio reached.
    """

    before: float = 0.3e-3
    after: float = 0.6e-3
    iterations: int = 250
    progress: bool = False


class _Window:
    """The search's problem: the plan's drive plus a correction over the window around T_F, played
    on the exact plant of every mode from the window's start to the end of the shot; the p-norm of
    its off-target field and that norm's exact gradient."""

    def __init__(self, model: ModalModel, voltages: np.ndarray, focus_index: int, sample_rate: float, target_mask,
                 search: Search):
        self.model = model
        self.plant = Plant(model, sample_rate)
        self.backward = Plant(replace(model, actuator_gains=np.eye(model.n_modes)), sample_rate)
        self.outside = np.flatnonzero(~np.asarray(target_mask, bool))
        self.every = model.shapes[:, self.outside]
        self.start = max(0, focus_index - int(round(search.before * sample_rate)))
        self.width = min(voltages.shape[1], focus_index + int(round(search.after * sample_rate))) - self.start
        self.focus = focus_index - self.start
        self.base = self.plant.simulate(voltages)[:, self.start:]  # every mode, from the window on
        self.focus_field = model.shapes.T @ self.base[:, self.focus]
        self.peak = float(np.max(np.abs(self.focus_field)))
        self.actuators, self.tail = voltages.shape[0], self.base.shape[1]
        self.evaluations = 0  # plant runs (forward and adjoint pairs)

    def response(self, z: np.ndarray) -> np.ndarray:
        """Every mode's velocity from the window's start on with the correction ``z`` added."""
        drive = np.zeros((self.actuators, self.tail))
        drive[:, :self.width] = z.reshape(self.actuators, self.width)
        return self.base + self.plant.simulate(drive)

    def ratio(self, velocity: np.ndarray, shapes: np.ndarray | None = None) -> float:
        """The largest off-target |w| (at the points of ``shapes``, default every one) over the focus peak."""
        shapes = self.every if shapes is None else shapes
        return float(np.max(np.abs(shapes.T @ velocity)) / self.peak)

    def focus_change(self, velocity: np.ndarray) -> float:
        """Largest change of the field at T_F, relative to its peak."""
        return float(np.max(np.abs(self.model.shapes.T @ velocity[:, self.focus] - self.focus_field)) / self.peak)

    def objective(self, z: np.ndarray, p: int, shapes_out: np.ndarray) -> tuple[float, np.ndarray]:
        """The p-norm of the off-target field at the points of ``shapes_out`` plus the focus's
        penalty, and its gradient in ``z`` (the plant's transpose: the adjoint run backwards)."""
        model, peak, focus = self.model, self.peak, self.focus
        self.evaluations += 1
        velocity = self.response(z)
        off = shapes_out.T @ velocity / peak
        size = np.abs(off)
        top = size.max()
        scaled = size / top
        power = scaled.copy()
        for _ in range(int(np.log2(p))):  # p a power of two: squarings (5x faster than ** p)
            np.multiply(power, power, out=power)
        total = np.sum(power)
        norm = top * total ** (1 / p)
        change = (model.shapes.T @ velocity[:, focus] - self.focus_field) / peak
        with np.errstate(invalid="ignore", divide="ignore"):
            slope = np.where(size > 0, power / scaled, 0.0) * np.sign(off)  # scaled ** (p - 1), signed
        grad_velocity = shapes_out @ (total ** (1 / p - 1) * slope) / peak
        grad_velocity[:, focus] += model.shapes @ (2 * PENALTY * change) / peak
        adjoint = self.backward.simulate(grad_velocity[:, ::-1])[:, ::-1]  # the plant's transpose
        grad = (model.actuator_gains.T @ adjoint)[:, :self.width]
        return norm + PENALTY * float(change @ change), grad.ravel()


def refine(model: ModalModel, voltages: np.ndarray, focus_index: int, sample_rate: float, target_mask,
           margin: float, voltage_limit: float | None = None, search: Search = Search()) -> Refinement:
    """Find the correction of ``voltages`` (a, n) that brings the whole model's margin ratio to ``margin``.

    Parameters
    ----------
    model : ModalModel
        Every mode the structure is known to have.
    voltages : ndarray, shape (a, n)
        The plan's drive at ``sample_rate`` (Hz), V.
    focus_index : int
        DAC sample of T_F.
    target_mask : ndarray of bool, shape (n_points,)
    margin : float
        Ratio aimed at; the search stops once every sample meets it.
    voltage_limit : float, optional
        Largest |voltage| (V).
    search : Search
    """
    begin = _time.perf_counter()
    voltages = np.asarray(voltages, float)
    window = _Window(model, voltages, focus_index, sample_rate, target_mask, search)
    a, start, width = window.actuators, window.start, window.width
    reach = voltage_limit if voltage_limit is not None else float(np.max(np.abs(voltages)))
    held = voltages[:, start:start + width].ravel()
    bounds = list(zip(-reach - held, reach - held))
    best = np.zeros(a * width)
    ratio_before = window.ratio(window.base)
    bar = tqdm(total=search.iterations * len(STAGES), desc="margin on the whole model", unit="step",
               disable=not search.progress,
               leave=False)
    for p, points in STAGES:
        if window.ratio(window.response(best)) <= margin:
            break
        watched = window.every if points is None else window.every[:, ::max(1, window.outside.size // points)]
        best_ratio = window.ratio(window.response(best), watched)

        def check(intermediate_result):
            nonlocal best, best_ratio
            r = window.ratio(window.response(intermediate_result.x), watched)
            bar.update()
            bar.set_postfix(ratio=f"{r:.3f}", refresh=False)
            if r < best_ratio:
                best, best_ratio = intermediate_result.x.copy(), r
            if r <= margin:
                raise StopIteration

        result = minimize(window.objective, best, args=(p, watched), jac=True, method="L-BFGS-B", bounds=bounds,
                          callback=check, options={"maxiter": search.iterations, "maxcor": 30})
        r = window.ratio(window.response(result.x), watched)
        if r < best_ratio:
            best, best_ratio = result.x, r
    bar.close()
    velocity = window.response(best)
    return Refinement(best.reshape(a, width), start, window.ratio(velocity), ratio_before,
                      window.focus_change(velocity), _time.perf_counter() - begin, window.evaluations)
