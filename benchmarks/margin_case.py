"""The thesis's transient-margin case (al_sinc18_p4_margin) before and after optimization.

    python benchmarks/margin_case.py   # writes benchmarks/results/margin_case.{json,md} and margin_*.png

Thesis-al-cc, sinc 18 mm at 24 mm, 9 modes, T_F = 25 ms, margin 50%. Four plans: kappa = 1 (the
thesis's first try), the thesis's hand-tuned kappa {2: 7, 3: 3, 5: 5, 6: 3}, the casadi optimizer
(envelope rates and braking, margin on the planned modal field as in the thesis), and the
optimizer asked to hold the margin on the whole 21-mode model. Each is played on the HIL with a
perfect model: planned ratio, whole-model ratio, measured ratio, peak voltage, tau, solver time.
Also: plan time for 16 modes (10 mm sinc), median of repeats.
"""

from __future__ import annotations

import warnings

import numpy as np

from common import RESULTS, median_seconds, target, write_json
from modalctl.decompose import decompose
from modalctl.device import open_device
from modalctl.planner import PlanError, plan
from modalctl.report import plot_spacetime
from modalctl.run import run_open_loop
from modalctl.scenes import load_scene, thesis_tables


def main() -> None:
    warnings.simplefilter("ignore")
    case = thesis_tables()["experiments"]["al_sinc18_p4_margin"]
    model = load_scene("thesis-al-cc")
    shape = target(model, "sinc", width=f"{case['pulse_width_m']}m", center=f"{case['center_m']}m")
    tf, margin = case["focus_time_s"], case["transient_margin"]
    thesis_kappa = np.ones(case["modes_used"])
    for mode, k in case["kappa_found_by_trial_and_error"].items():
        thesis_kappa[int(mode) - 1] = k
    variants = [("kappa = 1", {"kappa": 1.0}), ("thesis kappa", {"kappa": thesis_kappa}),
                ("optimized", {"margin": margin}), ("optimized, whole model", {"margin": margin, "verify": "whole"})]
    rows = []
    for name, options in variants:
        device = open_device("sim://", model=model)
        try:
            shot = run_open_loop(model, shape, device, tf, modes=case["modes_used"], **options)
        except PlanError as exc:
            rows.append({"plan": name, "error": str(exc), "best_ratio": exc.needed})
            continue
        m, info = shot.metrics, shot.plan.info
        rows.append({"plan": name, "planned_ratio": info["predicted_margin_ratio"],
                     "whole_model_ratio": info["whole_model_margin_ratio"], "measured_ratio": m["margin_ratio"],
                     "peak_voltage": m["peak_voltage"], "tau": m["tau"], "plan_seconds": m["plan_seconds"],
                     "solver_seconds": m.get("optimizer", {}).get("seconds"), "kappa": m["kappa"], "brake": m["brake"]})
        slug = name.split(",")[0].replace(" ", "_").replace("=", "").replace("__", "_")
        plot_spacetime(shot, RESULTS / f"margin_{slug}.png")
    dec16 = decompose(model, target(model, "sinc", width="10mm", center="24mm"), 16)
    plan16 = median_seconds(lambda: plan(dec16, tf), 5)
    data = {"case": "al_sinc18_p4_margin", "margin": margin, "rows": rows, "plan_seconds_16_modes_median": plan16}
    write_json("margin_case", data)
    lines = ["# Transient margin: the thesis's case al_sinc18_p4_margin", "",
             "Command: `python benchmarks/margin_case.py`. HIL with a perfect model (all 21 modes), 1 MS/s.",
             "Planned: the kept modes' references (the thesis's criterion); whole model: the exact plant on all",
             "21 modes predicted by the planner; measured: the HIL run.", "",
             "| plan | planned ratio | whole-model ratio | measured ratio | peak V | tau | solver s |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['plan']} | refused: best reachable {r['best_ratio']:.3f} | | | | | |")
            continue
        solver = f"{r['solver_seconds']:.2f}" if r["solver_seconds"] is not None else "-"
        lines.append(f"| {r['plan']} | {r['planned_ratio']:.3f} | {r['whole_model_ratio']:.3f} | "
                     f"{r['measured_ratio']:.3f} | {r['peak_voltage']:.1f} | {r['tau']:.3f} | {solver} |")
    lines += ["", f"Plan time, 16 modes (10 mm sinc, no margin): median {plan16 * 1e3:.0f} ms.", ""]
    for r in rows:
        if "kappa" in r:
            lines.append(f"- {r['plan']}: kappa {np.round(r['kappa'], 2).tolist()}, brake {np.round(r['brake'], 2).tolist()}")
    (RESULTS / "margin_case.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
