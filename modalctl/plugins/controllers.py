"""First-party per-mode controllers: PI loops designed on margins, and a Kalman observer with LQ feedback.

Both are designed with python-control, which loads matplotlib's pyplot when imported: the modules
that design are imported when a controller is made, so that listing plugins or planning a shot
does not pay for it.
"""

from __future__ import annotations

from modalctl.loops.controller import Controller, ControllerFactory, LoopPlant
from modalctl.plugin.spec import hookimpl


def _pi(plant: LoopPlant, **options) -> Controller:
    from modalctl.loops.design import pi_controller

    return pi_controller(plant, **options)


def _lqg(plant: LoopPlant, **options) -> Controller:
    from modalctl.loops.lqg import LQGControl

    return LQGControl(plant, **options)


def _touch(plant: LoopPlant, inner: str = "pi", **options) -> Controller:
    from modalctl.loops.touch import TouchControl
    from modalctl.plugin.manager import get_controller

    return TouchControl(plant, get_controller(inner).create(plant), **options)


@hookimpl
def modalctl_controllers():
    return [ControllerFactory("pi", "PI per mode, zero on the mode's pole, the highest crossover that keeps "
                                    "50 deg and 6 dB with the lock-in and the latency (default)", _pi),
            ControllerFactory("lqg", "per-mode Kalman observer of the envelope model (detuning, latency, lock-in) "
                                     "with LQ state feedback and integral action", _lqg),
            ControllerFactory("touch", "PI per mode plus the force a touch takes: its damping and place estimated "
                                       "from every mode's envelope during the shot, given back on the planned motion",
                              _touch)]
