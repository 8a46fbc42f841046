"""What makes the truth differ from the controller's model: drift (fixed, or moving during the shot),
damping error, a finger on the surface, noise, amplifier."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from modalctl.model.modes import ModalModel
from modalctl.model.shape import Shape

__all__ = ["Perturbation", "perturb", "step", "ramp", "scan_noise", "DRIFT_MAX", "DRIFT_RATE_MAX",
           "DAMPING_ERROR_MAX", "FINGER_MAX", "SNR_MAX"]

# The largest departures a simulated truth may take (bad input beyond them, refused at the edge):
DRIFT_MAX = 0.5  # a resonance moved by half its frequency is another structure
DRIFT_RATE_MAX = 10.0  # 1/s: 25% over a 25 ms shot, far past any warming
DAMPING_ERROR_MAX = 10.0  # eleven times the modelled damping
FINGER_MAX = 100.0  # N s/m: a hundred times a pressing finger (0.1-1 N s/m)
SNR_MAX = 200.0  # dB: beyond, the noise is below float64's round-off of the signal


@dataclass(frozen=True)
class Perturbation:
    """A realistic departure of the structure and the electronics from the model.

    Attributes
    ----------
    drift : float
        Relative shift of every resonance frequency (0.01 = +1%, a few kelvin on aluminium).
    drift_spread : float
        Standard deviation of an extra random shift per mode (relative).
    damping_error : float
        Relative error of every damping ratio (0.2 = 20% more damping than modelled).
    snr_db : float or None
        Measurement noise: white, with a standard deviation of the shot's peak over 10^(snr/20)
        (the vibrometer: the peak velocity over the whole grid; each sensor: its own peak).
    amplifier_bandwidth : float or None
        First-order amplifier bandwidth (Hz).
    voltage_limit : float or None
        Amplifier rails (V).
    seed : int
        Random seed of the spread and the noise.
    drift_rate : float
        Further shift of every resonance during the shot, growing from the start (relative per
        second: 0.4 = +1% after 25 ms, a structure warming under its drive).
    drift_step : float
        Further shift of every resonance from ``drift_step_time`` (s) on (relative).
    drift_step_time : float
    finger : float
        Viscous damping of a finger resting on the surface (N s/m; 0: no finger); it couples the
        modes (:mod:`modalctl.hil.finger`).
    finger_at : tuple of float or None
        Where the finger rests (m; one coordinate on a beam, two on a plate).
    scan_repeats : int
        The vibrometer measures each point this many times and keeps the mean (the thesis's way to
        raise its signal-to-noise ratio): its noise falls by the square root (the sensors' does not).
    """

    drift: float = 0.0
    drift_spread: float = 0.0
    damping_error: float = 0.0
    snr_db: float | None = None
    amplifier_bandwidth: float | None = None
    voltage_limit: float | None = None
    seed: int = 0
    drift_rate: float = 0.0
    drift_step: float = 0.0
    drift_step_time: float = 0.0
    finger: float = 0.0
    finger_at: tuple | None = None
    scan_repeats: int = 1

    def __post_init__(self):
        if int(self.scan_repeats) != self.scan_repeats or self.scan_repeats < 1:
            raise ValueError(f"scan_repeats must be a whole number of shots, 1 or more, got {self.scan_repeats!r}")
        if self.finger < 0:
            raise ValueError(f"finger damping must be zero or more N s/m, got {self.finger!r}")
        if self.finger and self.finger_at is None:
            raise ValueError("a finger needs a place to rest (finger_at, m)")
        if self.finger and self.moving:
            raise ValueError("a finger on a structure whose resonances move during the shot is not simulated: "
                             "give a fixed drift with the finger")
        if self.amplifier_bandwidth and (self.finger or self.moving):
            raise ValueError("the amplifier's bandwidth is not simulated with a finger or a drift during the shot")

    @classmethod
    def from_options(cls, options: dict, model: ModalModel, target: Shape | None = None) -> "Perturbation":
        """The perturbation the simulator's command-line options ask for (by dest, parsed to SI; see
        :func:`modalctl.plugins.transports.modalctl_add_options`); a finger rests on the target's
        peak unless placed. ValueError names what is wrong."""
        finger, at = options.get("finger", 0.0), options.get("finger_at")
        if at is not None and not finger:
            raise ValueError("--finger-at places a finger: give its damping too (--finger, e.g. 0.5Ns/m)")
        if finger and at is None:
            if target is None:
                raise ValueError("--finger needs --finger-at here (no target to rest it on)")
            at = tuple(model.grid.points[int(np.argmax(np.abs(target.values)))])
        step, step_time = options.get("drift_step", (0.0, 0.0))
        return cls(drift=options.get("drift", 0.0), drift_spread=options.get("drift_spread", 0.0),
                   damping_error=options.get("damping_error", 0.0), snr_db=options.get("snr"),
                   amplifier_bandwidth=options.get("amplifier_bandwidth"), voltage_limit=options.get("rails"),
                   seed=options.get("seed", 0), drift_rate=options.get("drift_rate", 0.0), drift_step=step,
                   drift_step_time=step_time, finger=finger, finger_at=at,
                   scan_repeats=options.get("scan_repeats", 1))

    @property
    def moving(self) -> bool:
        """Whether the resonances move during the shot."""
        return bool(self.drift_rate or self.drift_step)

    def shift(self, t: float) -> float:
        """Further relative shift of every resonance at time ``t`` (s) of the shot."""
        return float(ramp(0.0, self.drift_rate)(t, 1)[0] + step(self.drift_step_time, self.drift_step)(t, 1)[0])

    def schedule(self):
        """``drift(t, k) -> (k,)`` for the HIL board, or None when the resonances hold still."""
        return (lambda t, k: np.full(k, self.shift(t))) if self.moving else None

    def describe(self) -> str:
        """One line for tables and reports."""
        parts = [f"drift {100 * self.drift:+.1f}%" if self.drift else "",
                 f"spread {100 * self.drift_spread:.1f}%" if self.drift_spread else "",
                 f"damping {100 * self.damping_error:+.0f}%" if self.damping_error else "",
                 f"SNR {self.snr_db:g} dB" if self.snr_db is not None else "",
                 f"amplifier {self.amplifier_bandwidth / 1e3:g} kHz" if self.amplifier_bandwidth else "",
                 f"rails {self.voltage_limit:g} V" if self.voltage_limit else "",
                 f"drift {100 * self.drift_rate:+g}%/s" if self.drift_rate else "",
                 f"drift step {100 * self.drift_step:+g}% at {1e3 * self.drift_step_time:g} ms"
                 if self.drift_step else "",
                 f"finger {self.finger:g} N s/m at {', '.join(f'{1e3 * x:g}' for x in self.finger_at)} mm"
                 if self.finger else "",
                 f"vibrometer mean of {self.scan_repeats}" if self.scan_repeats > 1 and self.snr_db is not None
                 else ""]
        return ", ".join(p for p in parts if p) or "perfect model"


def perturb(model: ModalModel, p: Perturbation) -> ModalModel:
    """The truth model: ``model`` with drifted resonances and erred damping (shapes unchanged)."""
    rng = np.random.default_rng(p.seed)
    shift = 1 + p.drift + p.drift_spread * rng.standard_normal(model.n_modes)
    return replace(model, frequencies=model.frequencies * shift,
                   damping=model.damping * (1 + p.damping_error))


def step(at: float, size: float):
    """``drift(t, k)``: every resonance shifts by ``size`` (relative) at time ``at`` (s)."""
    return lambda t, k: np.full(k, size if t >= at else 0.0)


def ramp(start: float, rate: float):
    """``drift(t, k)``: every resonance drifts at ``rate`` (relative per second) from ``start`` (s)."""
    return lambda t, k: np.full(k, rate * max(t - start, 0.0))


def scan_noise(key: tuple[int, ...], samples: np.ndarray, points: int, sigma: float) -> np.ndarray:
    """The bench vibrometer's noise (points, len(samples)) on one shot's record at these sample
    indices (m/s, standard deviation ``sigma``).

    Each sample's noise is drawn from a generator keyed by ``key`` (the shot) and the sample's
    index, so the vibrometer's record of a shot is one record: a scan reads the same noise however
    the host batches its requests (a transport asks a few thousand instants at a time).
    """
    samples = np.asarray(samples, int)
    unique, where = np.unique(samples, return_inverse=True)
    drawn = np.empty((points, unique.size))
    for j, index in enumerate(unique):
        drawn[:, j] = np.random.default_rng((*key, int(index))).standard_normal(points)
    return sigma * drawn[:, where.reshape(-1)]
