"""Speed against accuracy: focus time T_F against tau, margin and peak voltage on one scene.

    python benchmarks/focus_time.py   # writes benchmarks/results/focus_time.{json,png}

Thesis-al-cc, sinc 18 mm at 24 mm, 9 modes, open loop on the HIL, perfect model and a 1% drift of
every resonance, by both planners: the envelope planner as the thesis ran it (kappa = 1, no
margin) and the convex planner under the thesis's 0.5 margin. Plus the shortest T_F within a
voltage limit (bisection on each planner's feasibility; for the convex planner the exact bound of
its basis), with and without the margin.
"""

from __future__ import annotations

import warnings

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from common import command_line, open_loop, save_figure, target, write_json  # noqa: E402

from modalctl.hil.scenario import Perturbation  # noqa: E402
from modalctl.hil.sim_device import SimDevice  # noqa: E402
from modalctl.model.scenes import load_scene  # noqa: E402
from modalctl.options import THESIS_MARGIN, PlanOptions  # noqa: E402
from modalctl.plan.decompose import decompose  # noqa: E402
from modalctl.plan.planner import PlanError, min_focus_time  # noqa: E402

FOCUS_TIMES = [0.002, 0.003, 0.005, 0.0075, 0.01, 0.015, 0.025, 0.04]
LIMIT = 10.0  # V, for the min-focus-time search
PLANS = {"envelope, kappa = 1": PlanOptions(planner="envelope", margin=None),
         "convex, margin 0.5": PlanOptions(planner="convex", margin=THESIS_MARGIN)}
SHORTEST = {"envelope, kappa = 1, no margin": PlanOptions(planner="envelope", margin=None, voltage_limit=LIMIT),
            "convex, no margin": PlanOptions(planner="convex", margin=None, voltage_limit=LIMIT),
            "convex, margin 0.5": PlanOptions(planner="convex", margin=THESIS_MARGIN, voltage_limit=LIMIT)}
KEYS = ("tau", "margin_ratio", "peak_voltage", "plan_seconds", "sim_seconds")


def shot(model, shape, truth, tf, options: PlanOptions) -> dict:
    try:
        m = open_loop(model, shape, SimDevice(model, truth), tf, **options.but(modes=9).__dict__).to_dict()
    except PlanError as refused:
        return {"refused": str(refused), "smallest_ratio": refused.needed}
    return {k: m[k] for k in KEYS}


def main() -> None:
    warnings.simplefilter("ignore")
    model = load_scene("thesis-al-cc")
    shape = target(model, "sinc", width="18mm", center="24mm")
    rows = []
    for tf in FOCUS_TIMES:
        row = {"focus_time_s": tf}
        for plan_name, options in PLANS.items():
            for truth_name, truth in [("perfect", Perturbation()), ("drift 1%", Perturbation(drift=0.01))]:
                row[f"{plan_name}: {truth_name}"] = shot(model, shape, truth, tf, options)
        rows.append(row)
        print(tf, {k: v.get("tau", "refused") for k, v in row.items() if k != "focus_time_s"})
    dec = decompose(model, shape, 9)
    shortest = {}
    for name, options in SHORTEST.items():
        tf, found = min_focus_time(dec, options, lower=5e-4, upper=0.05)
        shortest[name] = {"focus_time_s": tf, "peak_voltage": found.report.peak_voltage,
                          "whole_model_ratio": found.report.whole_model_margin_ratio}
        print(f"shortest T_F within {LIMIT:g} V, {name}: {tf * 1e3:.2f} ms")
    data = {"rows": rows, "shortest": shortest, "min_focus_time_limit_v": LIMIT}
    write_json("focus_time", data)
    figure(data)


def _series(rows, key, field):
    return np.array([r[key].get(field, np.nan) for r in rows])


def figure(data) -> None:
    rows, shortest = data["rows"], data["shortest"]
    tf_ms = np.array([r["focus_time_s"] for r in rows]) * 1e3
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.5))
    colors = {"envelope, kappa = 1": "tab:orange", "convex, margin 0.5": "tab:blue"}
    for plan_name, color in colors.items():
        for truth, style in [("perfect", "o-"), ("drift 1%", "s--")]:
            key = f"{plan_name}: {truth}"
            axes[0].plot(tf_ms, _series(rows, key, "tau"), style, color=color, label=f"{plan_name}, {truth}")
            axes[1].plot(tf_ms, _series(rows, key, "margin_ratio"), style, color=color, label=f"{plan_name}, {truth}")
        axes[2].plot(tf_ms, _series(rows, f"{plan_name}: perfect", "peak_voltage"), "o-", color=color, label=plan_name)
    axes[1].axhline(0.5, color="r", ls=":", lw=1, label="thesis criterion")
    axes[2].axhline(data["min_focus_time_limit_v"], color="r", ls=":", lw=1)
    for (name, found), style in zip(shortest.items(), ["-.", ":", "--"]):
        axes[2].axvline(found["focus_time_s"] * 1e3, color="gray", ls=style, lw=1,
                        label=f"shortest T_F at {data['min_focus_time_limit_v']:g} V, {name}: "
                              f"{found['focus_time_s'] * 1e3:.2f} ms")
    for ax, label in zip(axes, ["tau", "margin ratio (whole shot)", "peak voltage (V)"]):
        ax.set_xscale("log")
        ax.set_xticks(tf_ms, [f"{t:g}" for t in tf_ms], fontsize=8)
        ax.minorticks_off()
        ax.set_xlabel("focus time T_F (ms)")
        ax.set_ylabel(label)
        ax.legend(frameon=False, fontsize=7)
    axes[2].set_yscale("log")
    fig.suptitle("thesis-al-cc, sinc 18 mm at 24 mm, 9 modes, open loop: the thesis's envelopes against the convex "
                 "planner under the 0.5 margin (a missing point: refused)", fontsize=10)
    save_figure(fig, "focus_time", dpi=110)


if __name__ == "__main__":
    command_line()
    main()
