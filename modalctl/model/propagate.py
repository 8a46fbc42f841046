"""Exact propagation of a modal structure driven by sampled voltages.

The HIL truth (:mod:`modalctl.hil.plant`) and the planner's predictions share it.

Each mode ``eta'' + 2 zeta w eta' + w^2 eta = f`` is split into partial fractions: its
velocity is ``2 Re(r z)`` with ``z' = lambda z + f``, ``lambda = -zeta w + j w_d`` and
``r = lambda / (lambda - conj(lambda))``. A first-order complex recursion is discretized
exactly for the input hold (zero-order hold: the DAC; first-order hold: straight lines
between samples, as python-control's ``forced_response`` assumes) and run by
``scipy.signal.lfilter``, one C loop per mode. An amplifier with a first-order bandwidth
``a`` is folded in exactly by the same partial fractions:
``a / ((s + a)(s - lambda)) = a / (lambda + a) (1/(s - lambda) - 1/(s + a))``.

No Euler step anywhere: for a sampled input the outputs at the samples are exact to
round-off, whatever the ratio of sample rate to resonance.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .modes import ModalModel, ModelError

__all__ = ["Plant", "hold_coefficients", "poles", "phasors_of", "HOLDS"]

HOLDS = ("zoh", "foh")


def hold_coefficients(poles: np.ndarray, dt: float, hold: str):
    """Exact discretization of ``z' = p z + u`` for a held input.

    Returns ``(E, g0, g1)`` such that ``z[n+1] = E z[n] + g0 u[n] + g1 u[n+1]``.

    Parameters
    ----------
    poles : ndarray, shape (k,)
        Complex poles p (1/s).
    dt : float
        Sample period (s).
    hold : {"zoh", "foh"}
    """
    p = np.asarray(poles, complex)
    pt = p * dt
    em1 = np.expm1(pt)
    i0 = em1 / p
    if hold == "zoh":
        return em1 + 1, i0, np.zeros_like(i0)
    if hold == "foh":
        # int_0^dt e^{p(dt - s)} s ds / dt, by series where p dt is small (cancellation)
        small = np.abs(pt) < 1e-3
        series = dt * (0.5 + pt / 6 + pt**2 / 24 + pt**3 / 120)
        g1 = np.where(small, series, (em1 - pt) / np.where(small, 1, p) ** 2 / dt)
        return em1 + 1, i0 - g1, g1
    raise ValueError(f"hold must be one of {HOLDS}, got {hold!r}")


class _Bank:
    """A bank of real filters ``y = 2 Re(r z)``, ``z' = p z + u``, one per row, with carried state.

    Each row is one lfilter call: for a complex pole the real second-order section
    ``(b0 + b1 q + b2 q^2) / (1 - 2 Re(E) q + |E|^2 q^2)``, ``q`` the unit delay; for a real
    pole a first-order one. The state starts at rest at the first sample.
    """

    def __init__(self, poles, residues, dt: float, hold: str):
        e, g0, g1 = hold_coefficients(poles, dt, hold)
        r = np.broadcast_to(np.asarray(residues, complex), e.shape)
        self._r, self._e, self._g0 = r, e, g0
        self.real = bool(np.all(np.asarray(poles).imag == 0))
        if self.real:
            self.b = np.stack([2 * (r * g1).real, 2 * (r * g0).real], axis=1)
            self.a = np.stack([np.ones(e.size), -e.real], axis=1)
            self.start = np.stack([-self.b[:, 0]], axis=1)
        else:
            self.b = np.stack([2 * (r * g1).real, 2 * (r * g0 - r * g1 * e.conj()).real,
                               -2 * (r * g0 * e.conj()).real], axis=1)
            self.a = np.stack([np.ones(e.size), -2 * e.real, np.abs(e) ** 2], axis=1)
            self.start = np.stack([-self.b[:, 0], 2 * (r * g0).real - self.b[:, 1]], axis=1)
        self.state = None

    def phasors(self, last_input: np.ndarray) -> np.ndarray:
        """The complex states ``z`` (rows) after the last sample, given that sample's input.

        The second-order section's state is ``s1 = 2 Re(r E z + r g0 x)`` and
        ``s2 = -2 Re(r g0 conj(E)) x - |E|^2 2 Re(r z)``: two real equations for ``z``.
        """
        if self.state is None:
            return np.zeros(self._e.shape, complex)
        r, e, g0, x = self._r, self._e, self._g0, np.asarray(last_input, float)
        p = 0.5 * (self.state[:, 0] - 2 * (r * g0).real * x)  # Re(r E z)
        q = -0.5 * (self.state[:, 1] + 2 * (r * g0 * e.conj()).real * x) / np.abs(e) ** 2  # Re(r z)
        re, rr = r * e, r
        det = -re.real * rr.imag + re.imag * rr.real
        zr = (-p * rr.imag + q * re.imag) / det
        zi = (re.real * q - rr.real * p) / det
        return zr + 1j * zi

    def set_phasors(self, z: np.ndarray, last_input: np.ndarray) -> None:
        """Set the state so that the complex states after the last sample are ``z``."""
        r, e, g0, x = self._r, self._e, self._g0, np.asarray(last_input, float)
        self.state = np.stack([2 * (r * e * z + r * g0 * x).real,
                               -2 * (r * g0 * e.conj()).real * x - np.abs(e) ** 2 * 2 * (r * z).real], axis=1)

    def run(self, force: np.ndarray) -> np.ndarray:
        """Filter a chunk ``force`` (rows, n); returns the outputs (rows, n) at the samples."""
        if self.state is None:
            self.state = self.start * force[:, :1]
        out = np.empty(force.shape)
        from scipy.signal import lfilter  # here: scipy.signal is a third of a second of every command's start

        for k in range(force.shape[0]):
            out[k], self.state[k] = lfilter(self.b[k], self.a[k], force[k], zi=self.state[k])
        return out


def poles(model: ModalModel) -> np.ndarray:
    """``-zeta w + j w sqrt(1 - zeta^2)`` of every mode (1/s), shape (k,)."""
    w, z = model.omega, model.damping
    return -z * w + 1j * w * np.sqrt(1 - z**2)


def phasors_of(poles: np.ndarray, displacement: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """The complex states ``z`` of the partial fractions with displacement ``2 Re(z q)`` and velocity
    ``2 Re(z q lambda)``, ``q = 1 / (lambda - conj(lambda))``: a mode's state in its pole's terms."""
    q = 1 / (poles - poles.conj())
    a, b = q, q * poles
    det = -a.real * b.imag + a.imag * b.real
    zr = 0.5 * (-displacement * b.imag + velocity * a.imag) / det
    zi = 0.5 * (a.real * velocity - b.real * displacement) / det
    return zr + 1j * zi


class Plant:
    """Exact sampled simulation of a modal model (the HIL truth).

    Parameters
    ----------
    model : ModalModel
        The truth: frequencies, damping, shapes, actuator and sensor gains.
    sample_rate : float
        Input and output sample rate (Hz).
    hold : {"zoh", "foh"}
        How the input behaves between samples.
    amplifier_bandwidth : float or None
        -3 dB bandwidth of a first-order amplifier (Hz); None for an ideal one.
    voltage_limit : float or None
        Amplifier rails (V): commands are clipped to +-limit.
    """

    def __init__(self, model: ModalModel, sample_rate: float, hold: str = "zoh",
                 amplifier_bandwidth: float | None = None, voltage_limit: float | None = None):
        if not sample_rate > 0:
            raise ModelError(f"sample_rate must be positive, got {sample_rate!r}")
        if np.any(model.damping >= 1):
            raise ModelError("plant: overdamped modes (zeta >= 1) are not supported")
        if hold not in HOLDS:
            raise ModelError(f"hold must be one of {HOLDS}, got {hold!r}")
        self.model, self.sample_rate, self.hold = model, float(sample_rate), hold
        self.amplifier_bandwidth, self.voltage_limit = amplifier_bandwidth, voltage_limit
        self.poles = poles(model)
        self.residues = self.poles / (self.poles - self.poles.conj())
        self._amp_pole = None
        if amplifier_bandwidth is not None:
            a = 2 * np.pi * amplifier_bandwidth
            self.residues = self.residues * a / (self.poles + a)
            self._amp_pole = -a
        self.clipped = 0
        self.reset()

    def reset(self) -> None:
        """Bring the structure back to rest."""
        dt = 1 / self.sample_rate
        self._modes = _Bank(self.poles, self.residues, dt, self.hold)
        self._last_force = np.zeros(self.model.n_modes)
        channels = self.model.actuator_gains.shape[1]
        self._amp = (_Bank(np.full(channels, self._amp_pole + 0j), 0.5, dt, self.hold)
                     if self._amp_pole is not None else None)
        self.clipped = 0

    def step(self, voltages: np.ndarray) -> np.ndarray:
        """Drive the plant with the next chunk of commands and return the modal velocities.

        Parameters
        ----------
        voltages : ndarray, shape (a, n)
            Commanded voltage per actuator at each sample (V).

        Returns
        -------
        ndarray, shape (k, n)
            Modal velocities at the same samples (m/s sqrt(kg)).
        """
        u = np.atleast_2d(np.asarray(voltages, float))
        if u.shape[0] != self.model.actuator_gains.shape[1]:
            raise ModelError(f"plant: {u.shape[0]} voltage channels for "
                             f"{self.model.actuator_gains.shape[1]} actuators")
        if self.voltage_limit is not None:
            self.clipped += int(np.count_nonzero(np.abs(u) > self.voltage_limit))
            u = np.clip(u, -self.voltage_limit, self.voltage_limit)
        gains = self.model.actuator_gains
        force = gains @ u
        velocity = self._modes.run(force)
        if force.shape[1]:
            self._last_force = force[:, -1]
        if self._amp is not None:
            velocity -= 2 * self.residues.real[:, None] * (gains @ self._amp.run(u))
        return velocity

    def modal_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Displacement and velocity of every mode after the last sample, shapes (k,), (k,)."""
        z = self._modes.phasors(self._last_force)
        q = 1 / (self.poles - self.poles.conj())
        return 2 * (z * q).real, 2 * (z * q * self.poles).real

    def retune(self, frequencies: np.ndarray, damping: np.ndarray | None = None) -> None:
        """Change the resonances (Hz) and damping mid-run, each mode's displacement and velocity
        continuous: the truth drifting (temperature) or a finger landing, between two chunks.

        Not available with an amplifier bandwidth (its state is not split per mode).
        """
        if self._amp is not None:
            raise ModelError("plant: retune does not support an amplifier bandwidth")
        eta, velocity = self.modal_state()
        damping = self.model.damping if damping is None else damping
        self.model = replace(self.model, frequencies=np.asarray(frequencies, float), damping=np.asarray(damping, float))
        self.poles = poles(self.model)
        self.residues = self.poles / (self.poles - self.poles.conj())
        bank = _Bank(self.poles, self.residues, 1 / self.sample_rate, self.hold)
        bank.set_phasors(phasors_of(self.poles, eta, velocity), self._last_force)
        self._modes = bank

    def simulate(self, voltages: np.ndarray) -> np.ndarray:
        """Modal velocities (k, n) for a whole shot from rest (see :meth:`step`)."""
        self.reset()
        return self.step(voltages)

    def sensors(self, modal_velocity: np.ndarray) -> np.ndarray:
        """Velocity at the sensors (s, n) from modal velocities (k, n) (m/s)."""
        return self.model.sensor_gains.T @ modal_velocity

    def field(self, modal_velocity: np.ndarray) -> np.ndarray:
        """Velocity on the grid (n_points, n) from modal velocities (k, n) (m/s)."""
        return self.model.shapes.T @ modal_velocity
