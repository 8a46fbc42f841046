"""Per-mode references: a carrier at the resonance under a rising envelope, and the exact drive.

Mode k obeys ``eta'' + 2 zeta w eta' + w^2 eta = f(t)`` (``f`` is the modal force per unit
modal mass, ``sum_a alpha_ka v_a``). Its velocity reference, with ``tau = t - T_F``:

* rise, ``-T_F <= tau <= 0``::

      r(tau) = e^{sigma tau} (A cos w tau + B sin w tau) + (c - A) cos w tau - B sin w tau

  with ``sigma = kappa zeta w``. At ``tau = 0`` its phasor is exactly ``c``: the mode crosses
  its target velocity at the focus time. ``A, B`` are chosen so that velocity *and*
  displacement are zero at ``t = 0``: the mode starts at rest, so the drive below is exact
  from the first sample (the thesis's Eq 2.33 starts with a jump that a mode at rest cannot
  follow; for mode 1 of the aluminium beam at ``T_F = 25 ms`` that jump is half the target).
  For ``kappa zeta w T_F >> 1``, ``A -> c`` and ``B -> 0``: the pure exponential of Eq 2.33.

* decay, ``tau > 0``: ``x(tau) = e^{-beta tau} (E cos w_d tau + F sin w_d tau)`` plus a short
  blending term, continuous in displacement, velocity and acceleration at ``T_F`` (so the drive
  is continuous too), with ``beta = b zeta w`` and ``w_d = w sqrt(1 - zeta^2)``. ``b = 1`` is the
  free decay (zero drive once the blend has died); ``b > 1`` brakes the mode.

The drive is the exact inverse dynamics ``f = r' + 2 zeta w r + w^2 eta``, not the thesis's
approximation ``2 (kappa + 1) zeta w c`` (which is its amplitude for ``kappa zeta w T_F >> 1``).

Every function takes an ``ops`` namespace (``numpy`` or ``casadi``) so the same formulas serve
the numerical plan and the symbolic optimizer. Shapes: mode parameters broadcast against
``tau``; with numpy use parameters of shape (k, 1) and ``tau`` of shape (1, nt).
"""

from __future__ import annotations

import numpy as np

__all__ = ["rise_coefficients", "rise", "decay", "focus_state", "modal_response"]

BLEND = 8.0  # the envelope turns from rise to decay over 1 / (BLEND (sigma + beta)) (see decay)


def rise_coefficients(c, omega, zeta, kappa, focus_time, ops=np):
    """Envelope coefficients ``(A, B)`` that start the mode at rest at ``t = 0``.

    Parameters
    ----------
    c : array_like
        Target modal velocity at the focus time (m/s sqrt(kg)).
    omega, zeta : array_like
        Resonance (rad/s) and damping ratio.
    kappa : array_like
        Envelope rate in units of the natural rate ``zeta omega`` (> 0).
    focus_time : float
        T_F (s).
    """
    sigma = kappa * zeta * omega
    rho = sigma**2 + omega**2
    e = ops.exp(-sigma * focus_time)
    co, si = ops.cos(-omega * focus_time), ops.sin(-omega * focus_time)
    m11, m12 = (e - 1) * co, (e - 1) * si
    m21 = e * (sigma * co + omega * si) / rho - si / omega
    m22 = e * (sigma * si - omega * co) / rho + co / omega
    r1, r2 = -c * co, -c * si / omega
    det = m11 * m22 - m12 * m21
    return (r1 * m22 - m12 * r2) / det, (m11 * r2 - m21 * r1) / det


def rise(tau, c, omega, zeta, kappa, focus_time, ops=np, derivatives=False):
    """Velocity (m/s sqrt(kg)), displacement and drive (force per unit modal mass) for ``tau <= 0``.

    With ``derivatives``, also the acceleration: (velocity, displacement, drive, acceleration).
    """
    a, b = rise_coefficients(c, omega, zeta, kappa, focus_time, ops)
    sigma = kappa * zeta * omega
    rho = sigma**2 + omega**2
    env = ops.exp(sigma * tau)
    co, si = ops.cos(omega * tau), ops.sin(omega * tau)
    cc, dd = c - a, -b
    velocity = env * (a * co + b * si) + cc * co + dd * si
    displacement = env * (a * (sigma * co + omega * si) + b * (sigma * si - omega * co)) / rho + (cc * si - dd * co) / omega
    accel = env * ((sigma * a + omega * b) * co + (sigma * b - omega * a) * si) + omega * (dd * co - cc * si)
    drive = accel + 2 * zeta * omega * velocity + omega**2 * displacement
    if derivatives:
        return velocity, displacement, drive, accel
    return velocity, displacement, drive


def decay(tau, c, start, omega, zeta, brake, rise_rate, ops=np):
    """Velocity, displacement and drive for ``tau >= 0``, continuous with the rise at T_F.

    ``x = e^{-beta tau} (E cos w_d tau + F sin w_d tau) + G e^{-beta2 tau} sin w_d tau`` matches the
    displacement and acceleration ``start = (x0, a0)`` (:func:`focus_state`) and the velocity ``c``
    of the rise at T_F, so the drive
    has no step there (a step would ring every other mode of the structure). In envelope terms
    the envelope turns smoothly from rising at ``rise_rate`` (1/s) to decaying at ``beta``: the
    blend term dies at ``beta2 = beta + BLEND (rise_rate + beta)`` and overshoots by about
    ``1 / BLEND`` of the target just after T_F. ``brake`` = 1 then decays freely (zero drive).
    """
    x0, a0 = start
    beta = brake * zeta * omega
    wd = omega * ops.sqrt(1 - zeta**2)
    beta2 = beta + BLEND * (rise_rate + beta)
    g_ = (a0 + 2 * beta * c + (beta**2 + wd**2) * x0) / (2 * wd * (beta - beta2))
    e_ = x0
    f_ = (c + beta * e_ - wd * g_) / wd
    env, env2 = ops.exp(-beta * tau), ops.exp(-beta2 * tau)
    co, si = ops.cos(wd * tau), ops.sin(wd * tau)
    v1, h = -beta * e_ + wd * f_, -(beta * f_ + wd * e_)
    displacement = env * (e_ * co + f_ * si) + g_ * env2 * si
    velocity = env * (v1 * co + h * si) + g_ * env2 * (wd * co - beta2 * si)
    accel = (env * ((-beta * v1 + wd * h) * co + (-beta * h - wd * v1) * si)
             + g_ * env2 * ((beta2**2 - wd**2) * si - 2 * beta2 * wd * co))
    drive = accel + 2 * zeta * omega * velocity + omega**2 * displacement
    return velocity, displacement, drive


def focus_state(c, omega, zeta, kappa, focus_time, ops=np):
    """Displacement and acceleration of the rise at T_F (its velocity is ``c``)."""
    x0, a0 = rise(0.0 * c, c, omega, zeta, kappa, focus_time, ops, derivatives=True)[1::2]
    return x0, a0


def modal_response(t, c, omega, zeta, kappa, brake, focus_time):
    """Planned velocity and drive of every mode at times ``t`` (numpy).

    Parameters
    ----------
    t : ndarray, shape (nt,)
        Times from the start of the shot (s); zero before 0.
    c, omega, zeta, kappa, brake : ndarray, shape (k,)

    Returns
    -------
    velocity, drive : ndarray, shape (k, nt)
    """
    t = np.asarray(t, float)
    col = [np.asarray(p, float).reshape(-1, 1) for p in (c, omega, zeta, kappa, brake)]
    c, omega, zeta, kappa, brake = col
    tau = t - focus_time
    velocity, drive = np.zeros((c.shape[0], t.size)), np.zeros((c.shape[0], t.size))
    rising, decaying = (tau <= 0) & (t >= 0), tau > 0  # each piece where it holds (zero before the shot)
    if rising.any():
        velocity[:, rising], _, drive[:, rising] = rise(tau[None, rising], c, omega, zeta, kappa, focus_time)
    if decaying.any():
        x0, a0 = focus_state(c, omega, zeta, kappa, focus_time)
        velocity[:, decaying], _, drive[:, decaying] = decay(tau[None, decaying], c, (x0, a0), omega, zeta, brake,
                                                             kappa * zeta * omega)
    return velocity, drive
