"""The thesis's transient-margin case (al_sinc18_p4_margin) before and after optimization.

    python benchmarks/margin_case.py   # writes benchmarks/results/margin_case.{json,md} and margin_*.png

Thesis-al-cc, sinc 18 mm at 24 mm, 9 modes, T_F = 25 ms, margin 50%. Four plans: kappa = 1 (the
thesis's first try), the thesis's hand-tuned kappa {2: 7, 3: 3, 5: 5, 6: 3}, the casadi optimizer
(envelope rates and braking, margin on the planned modal field as in the thesis), and the same
with the margin held on the whole 21-mode model (the voltages then corrected near the focus,
``modalctl.plan.refine``). Each is played on the HIL with a perfect model: planned ratio, whole-model
ratio, measured ratio, peak voltage, tau, solver time.
Also: plan time for 16 modes (10 mm sinc), median of repeats.
"""

from __future__ import annotations

import re
import warnings

import numpy as np
from common import RESULTS, command_line, median_seconds, open_loop, target, write_json

from modalctl.hil.sim_device import SimDevice
from modalctl.model.metrics import margin_ratio
from modalctl.model.propagate import Plant
from modalctl.model.scenes import load_scene, thesis_tables
from modalctl.options import THESIS_PLAN
from modalctl.plan.decompose import decompose
from modalctl.plan.planner import PlanError, plan
from modalctl.report import plot_spacetime


def steady_floor(model, shape, modes: int, focus_time: float, window: float = 100e-6):
    """Largest off-target ratio within ``window`` (s) of T_F if every kept mode's envelope were
    constant: ``sum_k c_k cos(w_k (t - T_F)) phi_k``, no transient at all. Returns (ratio, t - T_F)."""
    dec = decompose(model, shape, modes)
    k = dec.modes_used
    tau = np.arange(-window, window, 1e-6)
    field = model.shapes[k].T @ (dec.coefficients[k][:, None] * np.cos(model.omega[k][:, None] * tau))
    peak = np.max(np.abs(field[:, np.argmin(np.abs(tau))]))
    off = np.abs(field[~shape.target_mask]).max(axis=0) / peak
    return float(off.max()), float(tau[np.argmax(off)])


def strongest_unplanned(the_plan, count: int = 2, window: float = 0.3e-3):
    """The modes the plan left out that put the most velocity off target within ``window`` (s) of
    T_F, on the exact plant of the whole model: [(label, Hz, largest share of the focus peak)]."""
    model = the_plan.model
    velocity = Plant(model, the_plan.sample_rate).simulate(the_plan.voltages())
    near = np.abs(the_plan.times - the_plan.focus_time) < window
    left = np.setdiff1d(np.arange(model.n_modes), the_plan.modes)
    reach = np.abs(model.shapes[left][:, ~the_plan.target_mask]).max(axis=1)
    share = np.abs(velocity[left][:, near]).max(axis=1) * reach / the_plan.focus_peak
    top = np.argsort(share)[::-1][:count]
    return [(int(model.labels[left[i]]), float(model.frequencies[left[i]]), float(share[i])) for i in top]


def kept_modes_ratio(the_plan) -> float:
    """Margin ratio of the exact plant's field from the kept modes alone (the plan's drives, every
    cross-talk among the kept modes included, the modes it left out removed)."""
    velocity = Plant(the_plan.model, the_plan.sample_rate).simulate(the_plan.voltages())
    left = np.setdiff1d(np.arange(the_plan.model.n_modes), the_plan.modes)
    velocity[left] = 0.0
    t = the_plan.check_times()
    idx = np.clip(np.round(t * the_plan.sample_rate).astype(int), 0, velocity.shape[1] - 1)
    return margin_ratio(the_plan.model.shapes.T @ velocity[:, idx], t, the_plan.focus_time, the_plan.target_mask,
                        the_plan.focus_peak)[0]


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
                ("optimized", {"margin": margin, "margin_on": "kept"}),
                ("optimized, whole model", {"margin": margin, "margin_on": "whole"})]
    rows = []
    for name, options in variants:
        device = SimDevice(model)
        try:
            shot = open_loop(model, shape, device, tf, modes=case["modes_used"], **options)
        except PlanError as exc:
            rows.append({"plan": name, "error": str(exc), "best_ratio": exc.needed})
            continue
        m = shot.to_dict()
        rows.append({"plan": name, "planned_ratio": m["predicted_margin_ratio"],
                     "whole_model_ratio": m["whole_model_margin_ratio"], "measured_ratio": m["margin_ratio"],
                     "peak_voltage": m["peak_voltage"], "tau": m["tau"], "plan_seconds": m["plan_seconds"],
                     "solver_seconds": m.get("optimizer", {}).get("seconds"), "kappa": m["kappa"], "brake": m["brake"],
                     "refinement": shot.plan.report.refinement})
        if name == "optimized":
            culprits = strongest_unplanned(shot.plan)
            kept_only = kept_modes_ratio(shot.plan)
            kept_count = shot.plan.modes.size
            gains = np.linalg.svd(model.actuator_gains[shot.plan.modes], compute_uv=False)
        slug = re.sub(r"[^a-z0-9]+", "_", name).strip("_")  # kappa_1, thesis_kappa, optimized_whole_model
        plot_spacetime(shot, RESULTS / f"margin_{slug}.png")
    floor, at = steady_floor(model, shape, case["modes_used"], tf)
    dec16 = decompose(model, target(model, "sinc", width="10mm", center="24mm"), 16)
    plan16 = median_seconds(lambda: plan(dec16, tf, THESIS_PLAN), 5)
    data = {"case": "al_sinc18_p4_margin", "margin": margin, "rows": rows, "plan_seconds_16_modes_median": plan16,
            "steady_envelope_floor": {"ratio": floor, "t_minus_tf_s": at},
            "strongest_unplanned_modes": [{"mode": int(m), "hz": f, "off_target_share": v} for m, f, v in culprits],
            "optimized_kept_modes_only_ratio": kept_only, "kept_gain_singular_values": gains.tolist()}
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
        solver = "-" if r["solver_seconds"] is None else f"{r['solver_seconds']:.2f}"
        if r.get("refinement"):
            solver += f" + {r['refinement']['seconds']:.0f} (correction)"
        lines.append(f"| {r['plan']} | {r['planned_ratio']:.3f} | {r['whole_model_ratio']:.3f} | "
                     f"{r['measured_ratio']:.3f} | {r['peak_voltage']:.1f} | {r['tau']:.3f} | {solver} |")
    refined = next((r["refinement"] for r in rows if r.get("refinement")), None)
    lines += ["", f"Plan time, 16 modes (10 mm sinc, no margin): median {plan16 * 1e3:.0f} ms.", ""]
    if refined:
        lines += [f"Whole model: the voltage correction (L-BFGS-B on the exact 21-mode plant, its adjoint for the "
                  f"gradient, {refined['plant_runs']} plant runs) takes the whole-model ratio from "
                  f"{refined['ratio_before']:.3f} to {refined['ratio']:.3f} in {refined['seconds']:.0f} s, moving "
                  f"the focus field by {refined['focus_change']:.1e} of its peak, with corrections of at most "
                  f"{refined['largest_correction_v']:.1f} V over T_F - 0.3 ms .. T_F + 0.6 ms.", ""]
    lines += [f"Why the kept modes' plan alone does not hold {margin:g} on the whole structure: with the kept modes' envelopes held constant "
              f"(no transient at all) the field {at * 1e6:.0f} us after T_F already has an off-target peak of "
              f"{floor:.3f} of the focus peak: the targets' own evolution as the modes dephase. Any envelope "
              "that changes slowly over tens of microseconds keeps it; the optimizer brings the planned field to "
              f"{margin:g} only with the fast turn of its envelopes at T_F, and that fast turn also drives the "
              "modes the plan left out, which is what the whole-model and measured ratios show: within 0.3 ms of "
              "T_F the optimized plan puts off-target velocities of "
              + ", ".join(f"{share:.2f} of the focus peak in mode {label} ({f / 1e3:.1f} kHz)"
                          for label, f, share in culprits) + ". "
              f"The kept modes alone, on the exact plant, already reach {kept_only:.3f}: their fast drives leak into "
              f"one another, which the actuators cannot prevent ({kept_count} kept modes on "
              f"{model.actuator_gains.shape[1]} actuators: the kept modes' gain rows have singular values from "
              f"{gains.max():.3g} down to {gains.min():.2g}, so some of their combinations are barely separable), "
              "and the modes the plan left out add the rest. The correction above acts on exactly that: "
              "the field every mode makes, sample by sample.", ""]
    for r in rows:
        if "kappa" in r:
            lines.append(f"- {r['plan']}: kappa {np.round(r['kappa'], 2).tolist()}, brake {np.round(r['brake'], 2).tolist()}")
    (RESULTS / "margin_case.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    command_line()
    main()
