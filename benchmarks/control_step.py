"""Compute per control step of the per-mode loops: 21 modes, 8 actuators.

    python benchmarks/control_step.py   # writes benchmarks/results/control_step.{json,md}

One step = the Kalman observer of the envelope errors, the PI loops with anti-windup and the
dispatch of the mode commands to per-actuator phasors (8 x 21). Peer in the same run: the same
linear update written as python-control's discrete state space (the 21 PI loops as one MIMO
system on real I/Q channels, 42 states) stepped with ``dynamics`` and ``output``. Medians of
10,000 steps; the target is 50 us, so that a 10 kHz loop fits in Python.
"""

from __future__ import annotations

import time

import control
import numpy as np

from common import RESULTS, write_json
from modalctl.control import EnvelopeLoops, EnvelopeObserver, design_loops
from modalctl.dispatch import dispatch
from modalctl.scenes import load_scene

STEPS = 10_000
RATE = 20e3


def timed(step, steps: int = STEPS) -> np.ndarray:
    out = np.empty(steps)
    for i in range(steps):
        start = time.perf_counter()
        step(i)
        out[i] = time.perf_counter() - start
    return out


def main() -> None:
    model = load_scene("thesis-al-cc")
    modes = np.arange(model.n_modes)
    weights = dispatch(model, modes, np.ones(modes.size))  # (8, 21)
    design = design_loops(model.frequencies, model.damping, np.full(modes.size, 2e-4), RATE)
    loops = EnvelopeLoops(design, RATE, limit=np.full(modes.size, 1.0))
    observer = EnvelopeObserver(model.frequencies, model.damping, RATE, np.full(modes.size, 1e-3))
    rng = np.random.default_rng(0)
    errors = 1e-3 * (rng.standard_normal((STEPS, modes.size)) + 1j * rng.standard_normal((STEPS, modes.size)))
    envelope = np.ones(modes.size)
    command = np.zeros(modes.size, complex)

    def ours(i):
        nonlocal command
        filtered = observer.update(errors[i], command, envelope)
        command = loops.step(filtered)
        return weights * command[None, :]  # per-actuator phasor of each carrier

    # the same PI loops as python-control's discrete MIMO state space on the I/Q channels
    k = modes.size
    pi = control.c2d(control.ss(np.zeros((2 * k, 2 * k)), np.eye(2 * k), np.diag(np.repeat(design.ki, 2)),
                                np.diag(np.repeat(design.kp, 2))), 1 / RATE)
    state = np.zeros(2 * k)
    real_errors = np.stack([errors.real, errors.imag], axis=2).reshape(STEPS, 2 * k)

    def peer(i):
        nonlocal state
        y = pi.output(0, state, real_errors[i])
        state = pi.dynamics(0, state, real_errors[i])
        return weights * (y[0::2] + 1j * y[1::2])[None, :]

    times = {"modalctl": [], "python-control": []}
    for _ in range(3):  # interleaved
        times["modalctl"].append(np.median(timed(ours)))
        times["python-control"].append(np.median(timed(peer)))
    med = {name: float(np.median(v)) for name, v in times.items()}
    data = {"modes": k, "actuators": weights.shape[0], "steps": STEPS, "median_seconds": med,
            "ratio_peer_over_ours": med["python-control"] / med["modalctl"], "target_seconds": 50e-6}
    path = write_json("control_step", data)
    md = ["# Compute per control step, 21 modes and 8 actuators", "",
          "Command: `python benchmarks/control_step.py`. Median of 10,000 steps, 3 interleaved rounds.", "",
          "| implementation | median per step (us) |", "|---|---|",
          f"| modalctl: observer + PI loops + dispatch | {1e6 * med['modalctl']:.1f} |",
          f"| python-control discrete state space (PI only) + dispatch | {1e6 * med['python-control']:.1f} |", "",
          f"Ratio {data['ratio_peer_over_ours']:.1f}x; target 50 us (a 10 kHz loop in Python).", ""]
    (RESULTS / "control_step.md").write_text("\n".join(md))
    print("\n".join(md))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
