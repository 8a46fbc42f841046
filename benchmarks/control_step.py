"""Compute per control period of the runtime: 21 modes, 8 actuators.

    python benchmarks/control_step.py   # writes benchmarks/results/control_step.{json,md}

One period = :meth:`modalctl.loops.runtime.Runtime.update` minus the board: watchdog and divergence
checks, the envelope errors, the 21 PI loops with anti-windup, the supervisor's voltage and slew
limits and the dispatch of the mode commands to per-actuator phasors (8 x 21). The board is a
stub that answers at once (its time is not counted; the HIL board's is the plant's). Peer in the
same run: the PI part alone as python-control's discrete state space (the 21 loops as one MIMO
system on real I/Q channels, 42 states) stepped with ``dynamics`` and ``output``, plus the same
dispatch. Medians of 10,000 periods, three interleaved rounds; the target is 50 us, so that a
10 kHz loop fits in Python. Also: the same runtime with the disk log on.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import control
import numpy as np
from common import command_line, write_json, write_markdown

from modalctl.loops.design import design_loops
from modalctl.loops.lockin import lockin_bandwidths
from modalctl.loops.pi import PIControl
from modalctl.loops.recorder import Recorder
from modalctl.loops.runtime import LoopParts, PhasorBoard, Runtime, log_fields
from modalctl.loops.schedule import Schedule
from modalctl.loops.supervisor import Limits, Supervisor
from modalctl.model.scenes import load_scene
from modalctl.plan.dispatch import dispatch

STEPS = 10_000
RATE = 20e3


class StubBoard(PhasorBoard):
    """Answers every read at once with the next of a list of envelopes."""

    sensed = applied = None  # no records: the runtime alone is timed

    def __init__(self, readings):
        self.readings, self.n = readings, 0

    def configure(self, schedule):
        pass

    def start(self):
        self.n = 0

    def read(self):
        self.n += 1
        return self.readings[self.n % len(self.readings)]

    def write(self, phasors):
        pass

    def ramp_down(self, seconds):
        pass


def runtime(model, log=None):
    k = model.n_modes
    modes = np.arange(k)
    weights = dispatch(model, modes, np.ones(k))  # (8, 21)
    a = weights.shape[0]
    bands = lockin_bandwidths(model.frequencies, RATE, 1.0, 0.5)
    design = design_loops(model.frequencies, model.damping, bands, RATE)
    rng = np.random.default_rng(0)
    reference = 1e-4 * (1 + 0.1 * rng.standard_normal((k, STEPS + 1))) + 0j
    readings = list(reference.T[:1000] * (1 + 0.01 * rng.standard_normal((1000, k))))
    t = np.arange((STEPS + 1) * 25) / (25 * RATE)  # a 50 V feed-forward at 20 kHz on every channel
    ff = np.broadcast_to(50.0 * np.sin(2 * np.pi * 2e4 * t), (a, t.size))
    schedule = Schedule(RATE, 25, model.frequencies, bands, np.zeros((k, 4)), reference, reference, reference,
                        ff, weights)
    supervisor = Supervisor(Limits(100.0, 5e7), schedule, np.full(k, 1e-3))
    recorder = None if log is None else Recorder(log, log_fields(k, a))
    parts = LoopParts(schedule, PIControl(design, RATE), design, np.full((k, STEPS + 1), 1.0), np.zeros(k),
                      np.zeros(k), supervisor.limits)
    rt = Runtime(StubBoard(readings), parts, supervisor, recorder)
    rt.configure()
    rt.activate()
    return rt, design, weights


def timed(step, steps: int = STEPS) -> np.ndarray:
    out = np.empty(steps)
    for i in range(steps):
        start = time.perf_counter()
        step(i)
        out[i] = time.perf_counter() - start
    return out


def main() -> None:
    model = load_scene("thesis-al-cc")
    k = model.n_modes
    rng = np.random.default_rng(1)
    errors = 1e-6 * (rng.standard_normal((STEPS, k)) + 1j * rng.standard_normal((STEPS, k)))
    tmp = Path(tempfile.mkdtemp())

    def ours_factory(log=None):
        rt, design, weights = runtime(model, log)

        def step(i):
            if rt.period >= STEPS:
                rt.period = 0
            rt.update()
        return step, design, weights

    ours, design, weights = ours_factory()
    logged, _, _ = ours_factory(tmp / "log")
    pi = control.c2d(control.ss(np.zeros((2 * k, 2 * k)), np.eye(2 * k), np.diag(np.repeat(design.ki, 2)),
                                np.diag(np.repeat(design.kp, 2))), 1 / RATE)
    state = np.zeros(2 * k)
    real_errors = np.stack([errors.real, errors.imag], axis=2).reshape(STEPS, 2 * k)

    def peer(i):
        nonlocal state
        y = pi.output(0, state, real_errors[i])
        state = pi.dynamics(0, state, real_errors[i])
        return weights * (y[0::2] + 1j * y[1::2])[None, :]

    names = {"modalctl runtime update": ours, "modalctl runtime update + disk log": logged,
             "python-control state space (PI only) + dispatch": peer}
    times = {name: [] for name in names}
    for _ in range(3):  # interleaved rounds
        for name, step in names.items():
            times[name].append(float(np.median(timed(step))))
    med = {name: float(np.median(v)) for name, v in times.items()}
    ours_s, peer_s = med["modalctl runtime update"], med["python-control state space (PI only) + dispatch"]
    data = {"modes": k, "actuators": weights.shape[0], "steps": STEPS, "median_seconds": med,
            "ratio_peer_over_ours": peer_s / ours_s, "target_seconds": 50e-6, "target_met": ours_s < 50e-6}
    path = write_json("control_step", data)
    md = ["# Compute per control period, 21 modes and 8 actuators", "",
          "Command: `python benchmarks/control_step.py`. Median of 10,000 periods, 3 interleaved rounds; the board",
          "is a stub (its time is not counted).", "",
          "| implementation | median per period (us) |", "|---|---|",
          *[f"| {name} | {1e6 * s:.1f} |" for name, s in med.items()], "",
          "The runtime does watchdog, divergence check, errors, PI loops with anti-windup, voltage and slew",
          f"limits and dispatch; the peer only the PI loops and the dispatch. Ratio peer/ours "
          f"{data['ratio_peer_over_ours']:.2f}; target 50 us: {'met' if data['target_met'] else 'NOT met'}.", ""]
    write_markdown("control_step", md, path)


if __name__ == "__main__":
    command_line()
    main()
