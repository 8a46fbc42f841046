"""The simulator as a plugin: the ``sim://`` transport and its command-line options (the truth: how
the simulated structure differs from the model the shot is planned on).

The HIL registers itself through the ``modalctl`` entry point group exactly as a third party's
device would (``hil = "modalctl.hil.transport"`` in ``pyproject.toml``), so no module of the core,
the command line or the front door imports the simulator: they open ``sim://`` by URL.
"""

from __future__ import annotations

import argparse

from modalctl.io.device import Device, DeviceContext, TransportOptions
from modalctl.options import MODES_MAX, VOLTAGE_MIN
from modalctl.plugin.spec import hookimpl
from modalctl.units import number_type, quantity_type

from .scenario import (
    DAMPING_ERROR_MAX,
    DRIFT_MAX,
    DRIFT_RATE_MAX,
    FINGER_MAX,
    FINGER_PRESS_MAX,
    FINGER_SLIDE_MAX,
    FINGER_TIME_MAX,
    GAIN_ERROR_MAX,
    SNR_MAX,
)


def _sim(url: str, context: DeviceContext) -> Device:
    from .sim_device import SimDevice

    return SimDevice.from_url(url, context)


@hookimpl
def modalctl_transports():
    return {"sim": _sim}


def _drift_step(text: str) -> tuple[float, float]:
    """``SHIFT@TIME`` (``1%@20ms``) -> (relative shift, time in s)."""
    shift, at, time = text.partition("@")
    if not at:
        raise argparse.ArgumentTypeError(f"drift-step: expected SHIFT@TIME, e.g. 1%@20ms, got {text!r}")
    return (quantity_type("1", "drift-step")(shift),
            quantity_type("s", "drift-step time", low=0, low_open=False)(time))


@hookimpl
def modalctl_add_options(options: TransportOptions):
    """The simulator's truth: how the structure it simulates differs from the model planned on."""
    group = options.group("sim", "simulator truth (sim:// only)")
    group.add_argument("--truth", metavar="SCENE|MODEL.npz",
                       help="the structure simulated: a scene, or a model file on the same grid with the same "
                            "actuators and sensors (default: the --scene or --model itself)")
    group.add_argument("--truth-modes", type=number_type(int, "truth-modes", low=1, high=MODES_MAX, low_open=False),
                       metavar="N", help="the truth continued to its N lowest modes (a scene's structure or a "
                                         "finite-element plate's; spillover from the modes the model lacks)")
    group.add_argument("--drift", type=quantity_type("1", "drift", low=-DRIFT_MAX, high=DRIFT_MAX), default=0.0,
                       help="shift of every resonance, e.g. 1%%")
    group.add_argument("--drift-spread", type=quantity_type("1", "drift-spread", low=0, high=DRIFT_MAX, low_open=False),
                       default=0.0,
                       help="random extra shift per mode (standard deviation), e.g. 0.5%%")
    group.add_argument("--drift-rate", default=0.0,
                       type=quantity_type("1/s", "drift-rate", low=-DRIFT_RATE_MAX, high=DRIFT_RATE_MAX),
                       help="resonances moving during the shot, from its start, e.g. 40%%/s (+1%% at 25 ms)")
    group.add_argument("--drift-step", type=_drift_step, default=(0.0, 0.0), metavar="SHIFT@TIME",
                       help="every resonance jumps by SHIFT at TIME of the shot, e.g. 1%%@20ms")
    group.add_argument("--damping-error", type=quantity_type("1", "damping-error", low=-1, high=DAMPING_ERROR_MAX),
                       default=0.0,
                       help="relative damping error, e.g. 20%%")
    group.add_argument("--gain-error", type=quantity_type("1", "gain-error", low=0, high=GAIN_ERROR_MAX,
                                                          low_open=False), default=0.0,
                       help="each mode's actuator gains off by this, up or down by mode (drawn from --seed), "
                            "e.g. 20%%")
    group.add_argument("--finger", type=quantity_type("N s/m", "finger", low=0, high=FINGER_MAX, low_open=False),
                       default=0.0,
                       help="a finger resting on the surface: its viscous damping, e.g. 0.5Ns/m")
    group.add_argument("--finger-at", type=quantity_type("m", "finger-at", point=True), metavar="POINT",
                       help="where the finger rests, e.g. 24mm or 30mm,20mm (default: the target's peak)")
    group.add_argument("--finger-lands", type=quantity_type("s", "finger-lands", low=0, high=FINGER_TIME_MAX, low_open=False),
                       help="the finger lands at this time of the shot, e.g. 10ms (default: it rests from the start)")
    group.add_argument("--finger-lifts", type=quantity_type("s", "finger-lifts", low=0, high=FINGER_TIME_MAX),
                       help="the finger lifts at this time of the shot, e.g. 20ms (default: it stays)")
    group.add_argument("--finger-slide", default=0.0,
                       type=quantity_type("m/s", "finger-slide", low=-FINGER_SLIDE_MAX, high=FINGER_SLIDE_MAX),
                       help="the finger slides along x at this speed from where it landed, e.g. 50mm/s")
    group.add_argument("--finger-press", default=0.0,
                       type=quantity_type("N s/m/s", "finger-press", low=0, high=FINGER_PRESS_MAX, low_open=False),
                       help="the finger presses harder: its damping grows at this rate, e.g. 40Ns/m/s")
    group.add_argument("--snr", type=number_type(float, "snr", low=0, high=SNR_MAX, low_open=False),
                       help="measurement noise, dB below the largest velocity")
    group.add_argument("--scan-repeats", type=number_type(int, "scan-repeats", low=1, high=1000, low_open=False), default=1,
                       help="the vibrometer measures each point N times and keeps the mean (1)")
    group.add_argument("--amplifier-bandwidth", type=quantity_type("Hz", "amplifier-bandwidth", low=0),
                       help="first-order amplifier bandwidth, e.g. 100kHz")
    group.add_argument("--rails", type=quantity_type("V", "rails", low=VOLTAGE_MIN, low_open=False),
                       help="amplifier voltage rails (clipping)")
    group.add_argument("--seed", type=number_type(int, "seed", low=0, high=2**32 - 1, low_open=False), default=0, help="seed of the spread and the noise (0)")
