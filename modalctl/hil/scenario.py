"""What makes the truth differ from the controller's model: drift (fixed, or moving during the shot),
damping error, a finger on the surface, noise, amplifier."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from modalctl.errors import InputError
from modalctl.model.modes import ModalModel, ModelError
from modalctl.model.shape import Shape
from modalctl.model.touch import touch_at
from modalctl.options import VOLTAGE_MIN

from .vibrometer import NOISE_BLOCK, scan_noise  # noqa: F401  (the vibrometer's noise: its home is .vibrometer)

__all__ = ["Perturbation", "perturb", "step", "ramp", "scan_noise", "AMPLIFIER_MIN", "DRIFT_MAX", "DRIFT_RATE_MAX",
           "DAMPING_ERROR_MAX", "GAIN_ERROR_MAX", "FINGER_MAX", "SNR_MAX",
           "FINGER_SLIDE_MAX", "FINGER_PRESS_MAX", "FINGER_TIME_MAX"]

# The largest departures a simulated truth may take (bad input beyond them, refused at the edge):
DRIFT_MAX = 0.5  # a resonance moved by half its frequency is another structure
DRIFT_RATE_MAX = 10.0  # 1/s: 25% over a 25 ms shot, far past any warming
DAMPING_ERROR_MAX = 10.0  # eleven times the modelled damping
GAIN_ERROR_MAX = 0.9  # a mode driven at a tenth (or 1.9 times) of its modelled gain
FINGER_MAX = 100.0  # N s/m: a hundred times a pressing finger (0.1-1 N s/m)
AMPLIFIER_MIN = 1.0  # Hz: a first-order amplifier narrower passes nothing of a plate's modes (1e-300 Hz: a zero field)
SNR_MAX = 200.0  # dB: beyond, the noise is below float64's round-off of the signal
FINGER_SLIDE_MAX = 10.0  # m/s: a swipe; faster is no touch
FINGER_PRESS_MAX = 1e4  # N s/m per s: from nothing to FINGER_MAX in 10 ms
FINGER_TIME_MAX = 10.0  # s: a finger landing or lifting later than any shot lasts is a typo
PRESS_STEP = 250e-6  # s: a pressing finger's damping is played in steps this long


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
    gain_error : float
        Relative error of each mode's actuator gains, its sign drawn per mode from ``seed`` (0.2:
        every mode driven 20% more or 20% less than modelled by every patch).
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
    finger_lands, finger_lifts : float or None
        When the finger lands on the surface and lifts from it (s of the shot; None: at the
        start, never).
    finger_slide : float
        The finger slides along the first axis at this speed (m/s), from where it landed, and
        stops at the edge.
    finger_press : float
        The finger presses harder: its damping grows at this rate from when it landed (N s/m per s).
    scan_repeats : int
        The vibrometer measures each point this many times and keeps the mean (the thesis's way to
        raise its signal-to-noise ratio): its noise falls by the square root (the sensors' does not).
    """

    drift: float = 0.0
    drift_spread: float = 0.0
    damping_error: float = 0.0
    gain_error: float = 0.0
    snr_db: float | None = None
    amplifier_bandwidth: float | None = None
    voltage_limit: float | None = None
    seed: int = 0
    drift_rate: float = 0.0
    drift_step: float = 0.0
    drift_step_time: float = 0.0
    finger: float = 0.0
    finger_at: tuple | None = None
    finger_lands: float | None = None
    finger_lifts: float | None = None
    finger_slide: float = 0.0
    finger_press: float = 0.0
    scan_repeats: int = 1

    def __post_init__(self):
        if int(self.scan_repeats) != self.scan_repeats or self.scan_repeats < 1:
            raise InputError(f"scan_repeats must be a whole number of shots, 1 or more, got {self.scan_repeats!r}")
        if not 0 <= self.gain_error <= GAIN_ERROR_MAX:
            raise InputError(f"gain_error must lie in [0, {GAIN_ERROR_MAX:g}], got {self.gain_error!r}")
        if self.finger < 0:
            raise InputError(f"finger damping must be zero or more N s/m, got {self.finger!r}")
        if self.finger and self.finger_at is None:
            raise InputError("a finger needs a place to rest (finger_at, m)")
        touching = (self.finger_lands, self.finger_lifts, self.finger_slide or None, self.finger_press or None)
        if not self.finger and any(x is not None for x in touching):
            raise InputError("the finger's landing, lifting, sliding and pressing need a finger (finger damping, N s/m)")
        if self.finger_lands is not None and self.finger_lifts is not None and self.finger_lifts <= self.finger_lands:
            raise InputError(f"the finger lifts ({self.finger_lifts!r} s) before it lands ({self.finger_lands!r} s)")
        if self.finger and self.moving:
            raise InputError("a finger on a structure whose resonances move during the shot is not simulated: "
                             "give a fixed drift with the finger")
        if self.voltage_limit is not None and not self.voltage_limit >= VOLTAGE_MIN:
            raise InputError(f"the amplifier's rails must be at least {VOLTAGE_MIN:g} V, got {self.voltage_limit!r} V")
        if self.amplifier_bandwidth is not None and not AMPLIFIER_MIN <= self.amplifier_bandwidth:
            raise InputError(f"the amplifier's bandwidth must be at least {AMPLIFIER_MIN:g} Hz, got "
                             f"{self.amplifier_bandwidth!r} Hz")
        if self.amplifier_bandwidth and (self.finger or self.moving):
            raise InputError("the amplifier's bandwidth is not simulated with a finger or a drift during the shot")

    @classmethod
    def from_options(cls, options: dict, model: ModalModel, target: Shape | None = None) -> "Perturbation":
        """The perturbation the simulator's command-line options ask for (by dest, parsed to SI; see
        :func:`modalctl.hil.transport.modalctl_add_options`); a finger rests on the target's
        peak unless placed. ValueError names what is wrong."""
        finger, at = options.get("finger", 0.0), options.get("finger_at")
        if at is not None and not finger:
            raise InputError("--finger-at places a finger: give its damping too (--finger, e.g. 0.5Ns/m)")
        if finger and at is None:
            if target is None:
                raise InputError("--finger needs --finger-at here (no target to rest it on)")
            at = tuple(model.grid.points[int(np.argmax(np.abs(target.values)))])
        step, step_time = options.get("drift_step", (0.0, 0.0))
        return cls(drift=options.get("drift", 0.0), drift_spread=options.get("drift_spread", 0.0),
                   damping_error=options.get("damping_error", 0.0), gain_error=options.get("gain_error", 0.0),
                   snr_db=options.get("snr"),
                   amplifier_bandwidth=options.get("amplifier_bandwidth"), voltage_limit=options.get("rails"),
                   seed=options.get("seed", 0), drift_rate=options.get("drift_rate", 0.0), drift_step=step,
                   drift_step_time=step_time, finger=finger, finger_at=at,
                   finger_lands=options.get("finger_lands"), finger_lifts=options.get("finger_lifts"),
                   finger_slide=options.get("finger_slide", 0.0), finger_press=options.get("finger_press", 0.0),
                   scan_repeats=options.get("scan_repeats", 1))

    @property
    def moving(self) -> bool:
        """Whether the resonances move during the shot."""
        return bool(self.drift_rate or self.drift_step)

    def shift(self, t: float) -> float:
        """Further relative shift of every resonance at time ``t`` (s) of the shot."""
        return float(ramp(0.0, self.drift_rate)(t, 1)[0] + step(self.drift_step_time, self.drift_step)(t, 1)[0])

    @property
    def touch_moves(self) -> bool:
        """Whether the finger lands, lifts, slides or presses during the shot."""
        return bool(self.finger) and (self.finger_lands is not None or self.finger_lifts is not None
                                      or bool(self.finger_slide) or bool(self.finger_press))

    def touch_path(self, model: ModalModel):
        """Where the finger is at each time of the shot: a ``TouchPath`` (``t -> Touch | None``) for
        :class:`~modalctl.hil.finger.FingerPlant`, the resting :class:`~modalctl.model.touch.Touch`
        when it holds still, None without a finger. ModelError when it rests off the structure.
        The press is played in steps of ``PRESS_STEP``."""
        if not self.finger:
            return None
        rest = touch_at(model, self.finger_at, self.finger)
        if not self.touch_moves:
            return rest
        lands = self.finger_lands or 0.0
        lifts = np.inf if self.finger_lifts is None else self.finger_lifts
        start, (low, high) = np.array(model.grid.points[rest.index], float), model.grid.bounds

        def path(t: float):
            if not lands <= t < lifts:
                return None
            held = PRESS_STEP * np.floor((t - lands) / PRESS_STEP)
            at = start.copy()
            at[0] = np.clip(at[0] + self.finger_slide * (t - lands), low[0], high[0])
            try:
                return touch_at(model, at, self.finger + self.finger_press * held)
            except ModelError:  # slid over a hole or a rounded corner: no contact there
                return None
        return path

    def schedule(self):
        """``drift(t, k) -> (k,)`` for the HIL board, or None when the resonances hold still."""
        return (lambda t, k: np.full(k, self.shift(t))) if self.moving else None

    def describe(self) -> str:
        """One line for tables and reports."""
        parts = [f"drift {100 * self.drift:+.1f}%" if self.drift else "",
                 f"spread {100 * self.drift_spread:.1f}%" if self.drift_spread else "",
                 f"damping {100 * self.damping_error:+.0f}%" if self.damping_error else "",
                 f"actuator gains +-{100 * self.gain_error:.0f}% by mode" if self.gain_error else "",
                 f"SNR {self.snr_db:g} dB" if self.snr_db is not None else "",
                 f"amplifier {self.amplifier_bandwidth / 1e3:g} kHz" if self.amplifier_bandwidth else "",
                 f"rails {self.voltage_limit:g} V" if self.voltage_limit else "",
                 f"drift {100 * self.drift_rate:+g}%/s" if self.drift_rate else "",
                 f"drift step {100 * self.drift_step:+g}% at {1e3 * self.drift_step_time:g} ms"
                 if self.drift_step else "",
                 f"finger {self.finger:g} N s/m at {', '.join(f'{1e3 * x:g}' for x in self.finger_at)} mm"
                 if self.finger else "",
                 f"landing at {1e3 * self.finger_lands:g} ms" if self.finger_lands is not None else "",
                 f"lifting at {1e3 * self.finger_lifts:g} ms" if self.finger_lifts is not None else "",
                 f"sliding at {1e3 * self.finger_slide:g} mm/s" if self.finger_slide else "",
                 f"pressing {self.finger_press:g} N s/m per s" if self.finger_press else "",
                 f"vibrometer mean of {self.scan_repeats}" if self.scan_repeats > 1 and self.snr_db is not None
                 else ""]
        return ", ".join(p for p in parts if p) or "perfect model"


def perturb(model: ModalModel, p: Perturbation) -> ModalModel:
    """The truth model: ``model`` with drifted resonances, erred damping and erred actuator gains
    (shapes unchanged)."""
    rng = np.random.default_rng(p.seed)
    shift = 1 + p.drift + p.drift_spread * rng.standard_normal(model.n_modes)
    truth = replace(model, frequencies=model.frequencies * shift, damping=model.damping * (1 + p.damping_error))
    if p.gain_error:  # drawn after the spread: a seed's spread is the same with or without gain errors
        signs = rng.choice([-1.0, 1.0], model.n_modes)
        truth = replace(truth, actuator_gains=model.actuator_gains * (1 + p.gain_error * signs)[:, None])
    return truth


def step(at: float, size: float):
    """``drift(t, k)``: every resonance shifts by ``size`` (relative) at time ``at`` (s)."""
    return lambda t, k: np.full(k, size if t >= at else 0.0)


def ramp(start: float, rate: float):
    """``drift(t, k)``: every resonance drifts at ``rate`` (relative per second) from ``start`` (s)."""
    return lambda t, k: np.full(k, rate * max(t - start, 0.0))
