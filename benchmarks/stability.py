"""Where a per-mode loop goes unstable: detuning against loop delay, predicted and observed.

    python benchmarks/stability.py   # writes benchmarks/results/stability.{json,md,png}

One loop (thesis-al-cc mode 5, 5.7 kHz, designed for one period of latency at 20 kHz) tracks a
step in its reference while the mode sits ``detuning`` off its carrier and the board adds extra
periods of delay. Predicted: the closed-loop poles of the design's model (python-control, the
mode's envelope turning at the detuning, the lock-in's low-pass, the delay as a Pade
approximant; :func:`modalctl.loops.design.loop_poles`) on a fine grid, the boundary where the largest
real part crosses zero. Observed: the same loop on the HIL board (the whole structure, every
mode) for 40 ms after the step: unstable when the supervisor stops it or the error grows.
"""

from __future__ import annotations

from dataclasses import replace

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from common import command_line, save_figure, write_json, write_markdown  # noqa: E402

from modalctl.experiments.executor import LocalExecutor  # noqa: E402
from modalctl.experiments.focus import step_runtime  # noqa: E402
from modalctl.loops.design import loop_poles  # noqa: E402
from modalctl.loops.recorder import read_log  # noqa: E402
from modalctl.loops.runtime import State  # noqa: E402
from modalctl.model.scenes import load_scene  # noqa: E402
from modalctl.options import LoopOptions  # noqa: E402

MODE, RATE = 4, 20e3
DETUNING_HZ = np.linspace(-1500, 1500, 13)
EXTRA = np.arange(0, 13)  # periods the board adds to the designed one


def observe(point) -> dict:
    """One HIL run: the loop tracking a step with the mode detuned and the board late."""
    import tempfile

    detuning, extra = point
    model = load_scene("thesis-al-cc", 105)
    f = model.frequencies.copy()
    f[MODE] += detuning
    log = tempfile.mkdtemp() + "/log"
    runtime, *_ = step_runtime(model, MODE, truth=replace(model, frequencies=f), loop=LoopOptions(control_rate=RATE, controller="pi"),
                               periods=820, latency=int(extra), log=log)
    result = runtime.run()
    error = np.abs(read_log(log)[0]["measured"][:, 0] - 1e-4) / 1e-4
    quarter = max(1, error.size // 4)
    growing = np.sqrt(np.mean(error[-quarter:] ** 2)) > 1.5 * np.sqrt(np.mean(error[quarter:2 * quarter] ** 2))
    stopped = result.state == State.ERROR
    return {"detuning_hz": float(detuning), "extra_periods": int(extra), "stopped": stopped,
            "final_error": float(error[-1]), "unstable": bool(stopped or (growing and error[-1] > 0.05))}


def main() -> None:
    model = load_scene("thesis-al-cc", 105)
    runtime, design, sigma, band = step_runtime(model, MODE, loop=LoopOptions(control_rate=RATE, controller="pi"))
    fine_d = np.linspace(DETUNING_HZ[0], DETUNING_HZ[-1], 61)
    fine_l = np.linspace(0, EXTRA[-1], 49)
    growth = np.array([[loop_poles(design, 0, sigma, band, RATE, 1 + extra, 2 * np.pi * d).real.max()
                        for d in fine_d] for extra in fine_l])
    points = [(d, e) for e in EXTRA for d in DETUNING_HZ]
    observed = LocalExecutor().map(observe, points, progress=True)
    predicted_at = {(o["detuning_hz"], o["extra_periods"]): bool(
        loop_poles(design, 0, sigma, band, RATE, 1 + o["extra_periods"], 2 * np.pi * o["detuning_hz"]).real.max() > 0)
        for o in observed}
    agree = sum(predicted_at[(o["detuning_hz"], o["extra_periods"])] == o["unstable"] for o in observed)
    data = {"mode_hz": float(model.frequencies[MODE]), "crossover_hz": float(design.crossover_hz[0]),
            "phase_margin_deg": float(design.phase_margin_deg[0]), "gain_margin_db": float(design.gain_margin_db[0]),
            "lockin_hz": float(band), "observed": observed, "agreement": agree, "points": len(observed)}
    path = write_json("stability", data)
    fig, ax = plt.subplots(figsize=(9, 5.5))
    image = ax.contourf(fine_d, fine_l, np.sign(growth), levels=[-2, 0, 2], colors=["#d8f0d8", "#f6d0d0"])
    ax.contour(fine_d, fine_l, growth, levels=[0], colors="k", linewidths=1.2)
    for o in observed:
        ax.plot(o["detuning_hz"], o["extra_periods"], "x" if o["unstable"] else "o",
                color="r" if o["unstable"] else "g", ms=6, mfc="none")
    ax.set(xlabel="detuning of the mode from its carrier (Hz)", ylabel="extra loop delay (control periods of 50 us)",
           title=f"mode {MODE + 1} ({model.frequencies[MODE] / 1e3:.2f} kHz) PI loop, crossover "
                 f"{design.crossover_hz[0]:.0f} Hz, {design.phase_margin_deg[0]:.0f} deg / "
                 f"{design.gain_margin_db[0]:.1f} dB designed\nshaded: predicted by python-control (red: unstable)\n"
                 f"markers: observed on the HIL (o stable, x unstable), agreement {agree}/{len(observed)}")
    del image
    save_figure(fig, "stability")
    md = ["# Stability boundary of a per-mode loop: detuning against delay", "",
          "Command: `python benchmarks/stability.py`.", "",
          f"Mode {MODE + 1} at {data['mode_hz']:.0f} Hz, lock-in {band:.0f} Hz, PI crossover "
          f"{data['crossover_hz']:.0f} Hz with {data['phase_margin_deg']:.1f} deg and {data['gain_margin_db']:.1f} dB "
          "designed for one period of latency at 20 kHz.",
          f"Predicted (closed-loop poles of the design model) and observed (HIL, 40 ms after a step) agree on "
          f"{agree} of {len(observed)} points. Picture: `stability.png`.", ""]
    write_markdown("stability", md, path)


if __name__ == "__main__":
    command_line()
    main()
