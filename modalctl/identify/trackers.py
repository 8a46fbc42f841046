"""Online resonance tracking: every controlled mode's frequency and damping while it is driven.

In its carrier's rotating frame a mode is a first-order complex system, and between control
samples (period T), with the drive envelope held linear,

    y[n] = a y[n-1] + b0 f[n-1] + b1 f[n],     a = exp((-zeta w + j (w_d - w_c)) T)

where ``y`` and ``f`` are the lock-in envelopes of the mode's response and drive (the same
low-pass applied to both keeps the relation; two input taps also absorb the other modes'
quasi-static answer to the drive). :class:`RLSTracker` estimates ``(a, b0, b1)``
per mode by recursive least squares with exponential forgetting, all modes at once (numpy
over modes), and reads the resonance and damping from ``a``. It retunes a mode's carrier when
the estimate leaves the carrier by more than a fraction of the half-power bandwidth (the
drive then stays on the resonance), and says when a mode is unexcited (no drive to learn
from: estimates frozen) or lost (the model no longer explains the response).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

__all__ = ["RLSTracker", "PoleTracker", "TrackerTuning", "updated_model", "TRACKING",
           "UNEXCITED", "LOST", "TrackerFactory"]

TRACKING, UNEXCITED, LOST = "tracking", "unexcited", "lost"


class TrackerFactory(ABC):
    """An online tracker as plugins provide them (hook ``modalctl_trackers``): a subclass names
    itself and makes a tracker of the given modes.

    Attributes
    ----------
    name, summary : str
    """

    name: str = ""
    summary: str = ""

    @abstractmethod
    def create(self, frequencies, damping, control_rate: float, **options):
        """A tracker of modes at ``frequencies`` (Hz) with ``damping`` (ratios), shape (k,), updated at
        ``control_rate`` (Hz): an object with ``update(response, drive)``, ``frequencies``,
        ``damping``, ``carriers`` and ``status`` per mode (see :class:`RLSTracker`)."""


@dataclass(frozen=True)
class TrackerTuning:
    """How a tracker weighs and judges what it learns.

    Attributes
    ----------
    memory : float
        Forgetting time constant (s), at least: the estimates follow changes over about this
        long. A mode whose own time constant ``1 / (zeta w)`` is longer gets ``settle`` times
        that instead (its response carries no faster information).
    settle : float
    retune : float
        Retune a carrier when the estimate is off by this fraction of ``zeta f`` (``inf``: never).
    lost_error : float
        A mode is lost when the RMS prediction error exceeds this fraction of its RMS response,
        or when its estimate leaves the model's resonance by more than ``max_drift`` (relative).
    min_drive : float
        A mode driven below this fraction of its largest drive so far is unexcited (frozen).
    max_drift : float
    """

    memory: float = 2e-3
    settle: float = 0.5
    retune: float = 0.1
    lost_error: float = 0.3
    min_drive: float = 1e-3
    max_drift: float = 0.05


class RLSTracker:
    """Per-mode recursive least squares on the demodulated envelopes.

    Parameters
    ----------
    frequencies, damping : array_like, shape (k,)
        The model's resonances (Hz) and damping ratios: the first carriers and estimates.
    control_rate : float
        Envelope sample rate (Hz).
    tuning : TrackerTuning
    """

    @classmethod
    def create(cls, frequencies, damping, control_rate: float, **tuning) -> "RLSTracker":
        """The tracker plugins' factory: ``tuning`` names :class:`TrackerTuning`'s fields."""
        return cls(frequencies, damping, control_rate, TrackerTuning(**tuning))

    def __init__(self, frequencies, damping, control_rate: float, tuning: TrackerTuning = TrackerTuning()):
        memory, settle, retune = tuning.memory, tuning.settle, tuning.retune
        lost_error, min_drive, max_drift = tuning.lost_error, tuning.min_drive, tuning.max_drift
        self.frequencies = np.array(frequencies, float)
        self.damping = np.array(damping, float)
        self.carriers = self.frequencies.copy()
        self.model_frequencies = self.frequencies.copy()
        self.period = 1 / float(control_rate)
        w = 2 * np.pi * self.frequencies
        self.memory = np.maximum(memory, settle / (self.damping * w))
        self.forget = np.exp(-self.period / self.memory)
        self.retune_fraction, self.lost_error, self.min_drive = retune, lost_error, min_drive
        self.max_drift = max_drift
        k = self.frequencies.size
        a0 = np.exp(-self.damping * w * self.period)
        self.theta = np.zeros((k, 3), complex)
        self.theta[:, 0] = a0
        self.P = np.tile(np.eye(3, dtype=complex) * 1e4, (k, 1, 1))
        self._prev = np.zeros((k, 2), complex)  # y[n-1], f[n-1]
        self._scale = None
        self._err = np.zeros(k)
        self._power = np.full(k, 1e-30)
        self._drive = np.zeros(k)
        self.status = np.full(k, UNEXCITED, dtype=object)
        self.retuned = np.zeros(k, int)

    def update(self, response: np.ndarray, drive: np.ndarray) -> None:
        """Learn from new envelopes, shapes (k, m) complex: the mode's response and its drive."""
        response, drive = np.atleast_2d(response), np.atleast_2d(drive)
        if self._scale is None:  # drive level from the first block, response level from the model at resonance
            drive_rms = np.maximum(np.sqrt(np.mean(np.abs(drive) ** 2, axis=1)), 1e-30)
            self._scale = drive_rms / (2 * self.damping * 2 * np.pi * self.frequencies), drive_rms
        y_all, f_all = response / self._scale[0][:, None], drive / self._scale[1][:, None]
        lam, smooth = self.forget, 1 - self.forget
        for y, f in zip(y_all.T, f_all.T):
            phi = np.column_stack([self._prev[:, 0], self._prev[:, 1], f])  # (k, 3)
            err = y - np.einsum("kj,kj->k", phi, self.theta)
            self._drive = (1 - smooth) * self._drive + smooth * np.abs(f) ** 2
            self._err = (1 - smooth) * self._err + smooth * np.abs(err) ** 2
            self._power = (1 - smooth) * self._power + smooth * np.abs(y) ** 2
            learn = self._drive > self.min_drive
            pc = np.einsum("kij,kj->ki", self.P, phi.conj())
            gain = pc / (lam + np.einsum("kj,kj->k", phi, pc))[:, None]
            self.theta[learn] += gain[learn] * err[learn, None]
            self.P[learn] = (self.P[learn] - np.einsum("ki,kj->kij", gain[learn],
                                                       np.einsum("kj,kji->ki", phi[learn], self.P[learn]))) \
                / lam[learn, None, None]
            self._prev = np.column_stack([y, f])
        self._read()

    def _read(self) -> None:
        """Resonances and damping from ``a``; status; carrier retuning."""
        a = self.theta[:, 0]
        decay = -np.log(np.maximum(np.abs(a), 1e-300)) / self.period  # zeta w (1/s)
        detune = np.angle(a) / self.period  # w_d - w_c (rad/s)
        wd = 2 * np.pi * self.carriers + detune
        w = np.sqrt(wd**2 + decay**2)
        zeta = decay / w
        excited = self._drive > self.min_drive
        plausible = (zeta > 0) & (zeta < 0.3) & (np.abs(w / (2 * np.pi * self.model_frequencies) - 1) < self.max_drift)
        fits = self._err <= self.lost_error**2 * self._power
        self.status = np.where(~excited, UNEXCITED, np.where(plausible & fits, TRACKING, LOST)).astype(object)
        ok = self.status == TRACKING
        self.frequencies[ok] = w[ok] / (2 * np.pi)
        self.damping[ok] = zeta[ok]
        off = ok & (np.abs(self.frequencies - self.carriers) > self.retune_fraction * self.damping * self.frequencies)
        if off.any():
            delta = self.frequencies[off] - self.carriers[off]
            self.theta[off, 0] *= np.exp(-2j * np.pi * delta * self.period)
            self.carriers[off] = self.frequencies[off]
            self.retuned[off] += 1


class PoleTracker(RLSTracker):
    """Per-mode recursive least squares on the pole alone, the modal gain taken from the model.

    In the carrier's frame the lock-in envelopes obey ``y' = p y + r f`` with ``r`` the mode's
    velocity residue (``lambda / (lambda - conj(lambda))``, known from the model; the dispatch
    makes the modal force one per unit of drive). Discretized exactly for a linear drive between
    samples, ``y[n] - r (g0 f[n-1] + g1 f[n]) = a y[n-1]``: one complex unknown ``a = exp(p T)``
    per mode. Unlike the three-parameter fit, one complex exponential drive (a focus envelope, or
    a steady carrier) already determines it; a gain error ``e`` moves the pole by about ``e``
    times the distance from the drive's complex frequency to the pole.

    Parameters are those of :class:`RLSTracker`.
    """

    def update(self, response: np.ndarray, drive: np.ndarray) -> None:
        """Learn from new envelopes, shapes (k, m) complex: the mode's response and its drive."""
        from modalctl.model.propagate import hold_coefficients

        response, drive = np.atleast_2d(response), np.atleast_2d(drive)
        if self._scale is None:
            self._scale = np.ones(response.shape[0])
            self.P = np.full(response.shape[0], 1e4)  # scalar covariance per mode
        level = np.maximum(np.sqrt(np.mean(np.abs(response) ** 2, axis=1)), 1e-300)
        grow = level > self._scale  # one common scale for y and f (the relation is homogeneous)
        self._prev[grow] *= (self._scale[grow] / level[grow])[:, None]
        self._scale = np.where(grow, level, self._scale)
        y_all, f_all = response / self._scale[:, None], drive / self._scale[:, None]
        a = self.theta[:, 0]
        p = np.log(a) / self.period
        w = 2 * np.pi * self.carriers
        lam = p + 1j * w  # pole in the fixed frame
        r = lam / (lam - lam.conj())
        _, g0, g1 = hold_coefficients(p, self.period, "foh")
        lam_f, smooth = self.forget, 1 - self.forget
        for y, f in zip(y_all.T, f_all.T):
            target = y - r * (g0 * self._prev[:, 1] + g1 * f)
            phi = self._prev[:, 0]
            err = target - a * phi
            self._drive = (1 - smooth) * self._drive + smooth * np.abs(f) ** 2 / (np.abs(f) ** 2 + np.abs(y) ** 2 + 1e-300)
            self._err = (1 - smooth) * self._err + smooth * np.abs(err) ** 2
            self._power = (1 - smooth) * self._power + smooth * np.abs(y) ** 2
            learn = np.abs(f) > 0
            gain = self.P * phi.conj() / (lam_f + self.P * np.abs(phi) ** 2)
            a = np.where(learn, a + gain * err, a)
            self.P = np.where(learn, (self.P - gain * phi * self.P) / lam_f, self.P)
            self._prev = np.column_stack([y, f])
        self.theta[:, 0] = a
        self._read()


def updated_model(model, modes, tracker, others: str = "shift"):
    """``model`` with the tracked modes' resonances and damping replaced by the tracker's
    estimates where it is tracking: what the planner and the controllers plan the next shot with.

    Parameters
    ----------
    model : ModalModel
    modes : sequence of int
        Positional indices in ``model`` of the tracker's modes, in its order.
    tracker : object with ``frequencies``, ``damping``, ``status``
    others : {"shift", "keep"}
        The resonances the tracker does not follow (modes not driven, or not tracking):
        ``"shift"`` moves them by the median relative shift of those it tracks (a uniform change
        of stiffness, such as temperature, moves every resonance alike; the median ignores one bad
        estimate), ``"keep"`` leaves the model's. Their damping stays the model's either way.
        Untracked modes matter to a transient margin: the off-target field is everyone's.
    """
    from dataclasses import replace

    if others not in ("shift", "keep"):
        raise ValueError(f"others must be 'shift' or 'keep', got {others!r}")
    f, z = np.array(model.frequencies, copy=True), np.array(model.damping, copy=True)
    ok = np.asarray(tracker.status) == TRACKING
    idx = np.asarray(modes, int)[ok]
    f[idx], z[idx] = np.asarray(tracker.frequencies)[ok], np.asarray(tracker.damping)[ok]
    if others == "shift" and idx.size:
        rest = np.setdiff1d(np.arange(f.size), idx)
        f[rest] *= np.median(f[idx] / np.asarray(model.frequencies)[idx])
    return replace(model, frequencies=f, damping=z)
