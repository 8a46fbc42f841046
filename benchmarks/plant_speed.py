"""HIL plant speed and accuracy against python-control's forced_response and scipy's lsim.

    python benchmarks/plant_speed.py   # writes benchmarks/results/plant_speed.{json,md}

Same 21-mode system (thesis-al-cc, 8 actuators, modal velocities out), same input (the planned
drive of a 10 mm sinc with 16 modes, 1 MS/s, 29 ms), first-order hold in all three (the
peers' convention). Medians of interleaved repeats; ratios from this run.
"""

from __future__ import annotations

import warnings

import control
import numpy as np
from common import RESULTS, command_line, median_seconds, state_space, target, write_json
from scipy import signal

from modalctl.hil.plant import Plant
from modalctl.model.scenes import load_scene
from modalctl.plan.decompose import decompose
from modalctl.plan.planner import plan


def main() -> None:
    model = load_scene("thesis-al-cc", 201)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        the_plan = plan(decompose(model, target(model, "sinc", width="10mm", center="24mm"), 16), 0.025)
    u, t = the_plan.voltages(), the_plan.times
    sys = state_space(model)
    plant = Plant(model, the_plan.sample_rate, hold="foh")

    ours = plant.simulate(u)
    theirs = control.forced_response(sys, t, u).outputs
    lsim = signal.lsim((sys.A, sys.B, sys.C, sys.D), u.T, t)[1].T
    scale = np.max(np.abs(theirs))
    err_fr = float(np.max(np.abs(ours - theirs)) / scale)
    err_lsim = float(np.max(np.abs(ours - lsim)) / scale)

    times = {"plant": [], "forced_response": [], "lsim": []}
    for _ in range(5):  # interleaved, so that machine load hits all three alike
        times["plant"].append(median_seconds(lambda: plant.simulate(u), 5))
        times["forced_response"].append(median_seconds(lambda: control.forced_response(sys, t, u), 1))
        times["lsim"].append(median_seconds(lambda: signal.lsim((sys.A, sys.B, sys.C, sys.D), u.T, t), 1))
    med = {k: float(np.median(v)) for k, v in times.items()}
    shot = t[-1] + t[1]
    data = {"modes": model.n_modes, "actuators": u.shape[0], "samples": t.size, "sample_rate_hz": the_plan.sample_rate,
            "shot_seconds": shot, "median_seconds": med,
            "speedup_vs_forced_response": med["forced_response"] / med["plant"],
            "speedup_vs_lsim": med["lsim"] / med["plant"],
            "faster_than_real_time": shot / med["plant"],
            "max_relative_difference_vs_forced_response": err_fr,
            "max_relative_difference_vs_lsim": err_lsim}
    path = write_json("plant_speed", data)
    md = (f"# HIL plant against python-control and scipy\n\n"
          f"Same system ({model.n_modes} modes, {u.shape[0]} actuators, modal velocities out), same input "
          f"({t.size} samples at {the_plan.sample_rate / 1e6:g} MS/s, a planned 16-mode drive), first-order hold.\n"
          f"Command: `python benchmarks/plant_speed.py`. Medians of 5 interleaved rounds.\n\n"
          f"| method | median time (ms) | ratio to the plant | max relative difference |\n|---|---|---|---|\n"
          f"| modalctl Plant (exact, lfilter per mode) | {med['plant'] * 1e3:.2f} | 1 | - |\n"
          f"| control.forced_response | {med['forced_response'] * 1e3:.1f} | {data['speedup_vs_forced_response']:.0f}x slower "
          f"| {err_fr:.1e} |\n"
          f"| scipy.signal.lsim | {med['lsim'] * 1e3:.1f} | {data['speedup_vs_lsim']:.0f}x slower | {err_lsim:.1e} |\n\n"
          f"The plant runs {data['faster_than_real_time']:.1f}x faster than real time.\n")
    (RESULTS / "plant_speed.md").write_text(md)
    print(md)
    print(f"wrote {path}")


if __name__ == "__main__":
    command_line()
    main()
