"""The closed cycle: identify the HIL beam from scratch, then focus with the identified model.

    python benchmarks/identify_cycle.py   # writes benchmarks/results/identify_cycle.{json,md}

`modalctl identify` (SNR 40 dB, the survey's default identifier, 106 points) gives a model; each experiment of the thesis
on thesis-al-cc is then run open loop on the HIL (the true beam, no perturbation) twice: planned
with the identified model and with the true one on the same 106-point grid. Target: tau within
0.02 of each other.
"""

from __future__ import annotations

import time
import warnings

import numpy as np
from common import RESULTS, command_line, open_loop, target, write_json
from thesis_table import experiments

from modalctl.hil.scenario import Perturbation
from modalctl.hil.sim_device import SimDevice
from modalctl.identify.frf import Sweep
from modalctl.identify.survey import identify_device
from modalctl.model.scenes import load_scene


def main() -> None:
    truth = load_scene("thesis-al-cc")
    points = np.arange(0, truth.grid.n, 10)
    mass = truth.meta["density_kg_m3"] * truth.meta["width_m"] * truth.meta["thickness_m"]
    start = time.perf_counter()
    survey = identify_device(SimDevice(truth, Perturbation(snr_db=40, seed=7)), Sweep.design(100, 100e3, 4.0),
                             points, mass)
    identify_seconds = time.perf_counter() - start
    same_grid = load_scene("thesis-al-cc", points.size)
    rows = []
    for name, scene, shape_name, params, centres, modes, tf, _ in experiments():
        if scene != "thesis-al-cc":
            continue
        for centre in centres:
            taus = {}
            for which, model in (("identified", survey.model), ("true", same_grid)):
                shape = target(model, shape_name, **params, center=f"{centre}m")
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    shot = open_loop(model, shape, SimDevice(truth), tf, modes=modes or "auto")
                taus[which] = shot.metrics.tau
            label = f"{name} @ {centre * 1e3:g} mm"
            rows.append({"experiment": label, "tau_identified": taus["identified"], "tau_true": taus["true"],
                         "difference": taus["identified"] - taus["true"]})
            print(f"{label:34s} tau identified {taus['identified']:.4f}  true {taus['true']:.4f}")
    worst = max(abs(r["difference"]) for r in rows)
    data = {"identify_seconds": identify_seconds, "identified_modes": survey.model.n_modes, "rows": rows,
            "worst_abs_difference": worst, "notes": survey.notes}
    path = write_json("identify_cycle", data)
    md = ["# Closed cycle: identify the HIL beam, then focus with the identified model", "",
          "Command: `python benchmarks/identify_cycle.py`. Identification: SNR 40 dB, all actuators, "
          f"{survey.model.meta.get('identified_by', 'auto')}, "
          f"{points.size} points, {survey.model.n_modes} modes, {identify_seconds:.0f} s in all (simulated "
          "acquisition included). Runs: open loop, T_F 25 ms, the true beam with no perturbation, the thesis's "
          "mode sets (`auto` where the thesis gives none).", "",
          "| experiment | tau, identified model | tau, true model | difference |", "|---|---|---|---|"]
    md += [f"| {r['experiment']} | {r['tau_identified']:.4f} | {r['tau_true']:.4f} | {r['difference']:+.4f} |"
           for r in rows]
    md += ["", f"Largest |difference|: {worst:.4f} (target 0.02).", ""]
    (RESULTS / "identify_cycle.md").write_text("\n".join(md))
    print(f"wrote {path}")


if __name__ == "__main__":
    command_line()
    main()
