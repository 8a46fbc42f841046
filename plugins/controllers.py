"""First-party per-mode controllers: PI loops designed on margins, and a Kalman observer with LQ feedback."""

from __future__ import annotations

from modalctl.control import ControllerFactory, pi_controller
from modalctl.hookspecs import hookimpl
from modalctl.lqg import LQGControl


@hookimpl
def modalctl_controllers():
    return [ControllerFactory("pi", "PI per mode, zero on the mode's pole, the highest crossover that keeps "
                                    "50 deg and 6 dB with the lock-in and the latency (default)", pi_controller),
            ControllerFactory("lqg", "per-mode Kalman observer of the envelope model (detuning, latency, lock-in) "
                                     "with LQ state feedback and integral action", LQGControl)]
