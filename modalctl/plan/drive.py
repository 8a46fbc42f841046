"""What a plan plays: each kept mode's modal force over time, and what each channel adds on its own.

A plan's actuator voltages are ``weights @ forces(t) + channels(t)``: ``forces`` (m kept modes,
modal force per unit modal mass) go through the dispatch weights (volts per unit modal force of
each mode on each actuator), ``channels`` are volts added on each actuator directly. The DAC holds
each sample at the drive's value in the middle of its period (:meth:`modalctl.plan.planner.Plan.voltages`).

- :class:`EnvelopeDrive`: the thesis's references, a carrier at each mode's resonance under an
  exponential envelope with its exact inverse dynamics (:mod:`modalctl.plan.reference`); nothing
  per channel.
- :class:`SplineDrive`: each kept mode's complex envelope on its carrier as a sum of shifted Hann
  bumps, and each channel's voltage as a sum of shifted hats (triangles); the convex planner's
  variables (:mod:`modalctl.plan.convex`). Every basis function of a family is a time-shifted copy
  of one prototype, which is what makes the planner's exact predictions cheap.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from .reference import modal_response

__all__ = ["Drive", "EnvelopeDrive", "BumpFamily", "HatFamily", "SplineDrive", "hann", "hat"]


class Drive(ABC):
    """A plan's drive of its kept modes."""

    def rates(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Each kept mode's envelope rise and post-focus decay rates (units of ``zeta w``), shapes
        (m,), (m,), where the drive is made of exponential envelopes; None otherwise."""
        return None

    @abstractmethod
    def forces(self, t: np.ndarray) -> np.ndarray:
        """Each kept mode's modal force at instants ``t`` (s), shape (m, nt)."""

    def channels(self, t: np.ndarray, count: int) -> np.ndarray | None:
        """Volts each of ``count`` channels adds on its own at ``t``, shape (count, nt); None for none."""
        return None


@dataclass(frozen=True, eq=False)
class EnvelopeDrive(Drive):
    """Exponential envelopes on the kept modes' carriers (thesis Eqs 2.32-2.34, started at rest).

    Attributes
    ----------
    targets : ndarray, shape (m,)
        Velocity each mode's reference reaches at T_F (m/s sqrt(kg)), as commanded (after any
        cross-talk compensation).
    omega, zeta : ndarray, shape (m,)
        The kept modes' resonances (rad/s) and damping ratios.
    kappa, brake : ndarray, shape (m,)
    focus_time : float
    """

    targets: np.ndarray
    omega: np.ndarray
    zeta: np.ndarray
    kappa: np.ndarray
    brake: np.ndarray
    focus_time: float

    def rates(self):
        return self.kappa, self.brake

    def references(self, t) -> tuple[np.ndarray, np.ndarray]:
        """Each kept mode's planned velocity and modal force at ``t``: two arrays (m, nt)."""
        return modal_response(t, self.targets, self.omega, self.zeta, self.kappa, self.brake, self.focus_time)

    def forces(self, t):
        return self.references(t)[1]


def hann(width: int) -> np.ndarray:
    """The Hann bump sampled at the middle of each of its ``width`` DAC periods: copies shifted by
    ``width / 2`` samples sum to one."""
    return np.sin(np.pi * (np.arange(width) + 0.5) / width) ** 2


def hat(half: int) -> np.ndarray:
    """The triangle of ``2 half - 1`` samples peaking at 1 on its middle sample (linear
    interpolation between knots ``half`` samples apart)."""
    up = np.arange(1, half + 1) / half
    return np.concatenate([up, up[-2::-1]])


@dataclass(frozen=True, eq=False)
class BumpFamily:
    """Hann bumps of one width, one per offset, for every kept mode's carrier.

    Attributes
    ----------
    offsets : ndarray of int, shape (j,)
        First DAC sample of each bump.
    width : int
        Samples of each bump.
    """

    offsets: np.ndarray
    width: int

    def prototypes(self, omega: np.ndarray, sample_rate: float) -> np.ndarray:
        """Each carrier's bump from its first sample, ``hann(width) exp(j w (n + 1/2) / fs)``, shape (m, width)."""
        n = np.arange(self.width) + 0.5
        return hann(self.width)[None, :] * np.exp(1j * np.asarray(omega)[:, None] * n[None, :] / sample_rate)

    def phases(self, omega: np.ndarray, sample_rate: float, focus_time: float) -> np.ndarray:
        """``exp(j w (offset / fs - T_F))``: a bump's carrier, referred to T_F, at its first sample, shape (m, j)."""
        return np.exp(1j * np.asarray(omega)[:, None] * (self.offsets[None, :] / sample_rate - focus_time))


@dataclass(frozen=True, eq=False)
class HatFamily:
    """Hats (triangles) of one half-width on every channel, one per offset.

    Attributes
    ----------
    offsets : ndarray of int, shape (j,)
        First DAC sample of each hat.
    half : int
        Samples from a hat's first sample to its peak, and between knots.
    """

    offsets: np.ndarray
    half: int


@dataclass(frozen=True, eq=False)
class SplineDrive(Drive):
    """Each kept mode's complex envelope on its carrier as Hann bumps, and hats on every channel.

    Mode m's force is ``Re sum_j c_mj hann(t - t_j) exp(j w_m (t - T_F))`` summed over the bump
    families; channel a adds ``sum_j u_aj hat(t - t_j)``.

    Attributes
    ----------
    omega : ndarray, shape (m,)
        The kept modes' carriers (rad/s).
    focus_time, sample_rate : float
    bumps : tuple of BumpFamily
    envelope : tuple of ndarray
        Per family, the complex coefficients (m, j) (modal force, N/sqrt(kg)).
    hats : HatFamily or None
    volts : ndarray, shape (a, j), or None
        The hats' coefficients (V).
    """

    omega: np.ndarray
    focus_time: float
    sample_rate: float
    bumps: tuple
    envelope: tuple
    hats: HatFamily | None = None
    volts: np.ndarray | None = None

    def forces(self, t):
        return np.real(self.envelopes(t) * self.carriers(t))

    def carriers(self, t) -> np.ndarray:
        """``exp(j w_m (t - T_F))``, shape (m, t): each kept mode's carrier (a caller forming many
        drives on the same instants keeps it: it is half of :meth:`forces`' time)."""
        return np.exp(1j * self.omega[:, None] * (np.asarray(t, float)[None, :] - self.focus_time))

    def envelopes(self, t) -> np.ndarray:
        """Each kept mode's complex envelope at ``t``, shape (m, t): the sum of its bumps."""
        t = np.asarray(t, float)
        envelope = np.zeros((self.omega.size, t.size), complex)
        rising = t.size < 2 or bool(np.all(np.diff(t) >= 0))  # the instants in order: each bump a slice
        order = np.arange(t.size) if rising else np.argsort(t, kind="stable")
        ts = t[order]
        for family, coefficients in zip(self.bumps, self.envelope):
            span = family.width / self.sample_rate
            starts = family.offsets / self.sample_rate
            first, last = np.searchsorted(ts, starts), np.searchsorted(ts, starts + span)
            for j in range(starts.size):  # each bump where it lives only
                where = slice(first[j], last[j]) if rising else order[first[j]:last[j]]
                bump = np.sin(np.pi * (t[where] - starts[j]) / span) ** 2
                envelope[:, where] += coefficients[:, j:j + 1] * bump[None, :]
        return envelope

    def channels(self, t, count):
        if self.hats is None:
            return None
        t = np.asarray(t, float)
        dt = 1 / self.sample_rate
        width = self.hats.half * dt
        peaks = (self.hats.offsets + self.hats.half - 1 + 0.5) * dt  # each hat's peak instant
        out = np.zeros((self.volts.shape[0], t.size))
        order = np.argsort(t, kind="stable")
        ts = t[order]
        first, last = np.searchsorted(ts, peaks - width, side="right"), np.searchsorted(ts, peaks + width)
        for j in range(peaks.size):
            where = order[first[j]:last[j]]
            out[:, where] += self.volts[:, j:j + 1] * (1 - np.abs(t[where] - peaks[j]) / width)[None, :]
        return out
