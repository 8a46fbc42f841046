"""Speed against accuracy: focus time T_F against tau, margin and peak voltage on one scene.

    python benchmarks/focus_time.py   # writes benchmarks/results/focus_time.{json,png}

Thesis-al-cc, sinc 18 mm at 24 mm, 9 modes, open loop on the HIL, kappa = 1, perfect model and a
1% drift of every resonance; plus the shortest T_F that meets a voltage limit (min-focus-time mode).
"""

from __future__ import annotations

import warnings

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from common import open_loop, save_figure, target, write_json  # noqa: E402

from modalctl.hil.scenario import Perturbation  # noqa: E402
from modalctl.hil.sim_device import SimDevice  # noqa: E402
from modalctl.model.scenes import load_scene  # noqa: E402
from modalctl.options import PlanOptions  # noqa: E402
from modalctl.plan.decompose import decompose  # noqa: E402
from modalctl.plan.planner import min_focus_time  # noqa: E402

FOCUS_TIMES = [0.002, 0.003, 0.005, 0.0075, 0.01, 0.015, 0.025, 0.04]
LIMIT = 10.0  # V, for the min-focus-time search


def main() -> None:
    warnings.simplefilter("ignore")
    model = load_scene("thesis-al-cc")
    shape = target(model, "sinc", width="18mm", center="24mm")
    rows = []
    for tf in FOCUS_TIMES:
        row = {"focus_time_s": tf}
        for name, p in [("perfect", Perturbation()), ("drift 1%", Perturbation(drift=0.01))]:
            m = open_loop(model, shape, SimDevice(model, p), tf, modes=9).to_dict()
            row[name] = {k: m[k] for k in ("tau", "margin_ratio", "peak_voltage", "plan_seconds", "sim_seconds")}
        rows.append(row)
        print(tf, row["perfect"]["tau"], row["drift 1%"]["tau"], row["perfect"]["peak_voltage"])
    shortest, plan = min_focus_time(decompose(model, shape, 9), PlanOptions(voltage_limit=LIMIT), lower=5e-4,
                                    upper=0.05)
    data = {"rows": rows, "min_focus_time_s": shortest, "min_focus_time_limit_v": LIMIT,
            "min_focus_time_peak_v": plan.info["peak_voltage"]}
    write_json("focus_time", data)
    tf_ms = np.array(FOCUS_TIMES) * 1e3
    fig, axes = plt.subplots(1, 3, figsize=(13, 4))
    for name, style in [("perfect", "o-"), ("drift 1%", "s--")]:
        axes[0].plot(tf_ms, [r[name]["tau"] for r in rows], style, label=name)
        axes[1].plot(tf_ms, [r[name]["margin_ratio"] for r in rows], style, label=name)
    axes[2].plot(tf_ms, [r["perfect"]["peak_voltage"] for r in rows], "o-", color="C2")
    axes[2].axhline(LIMIT, color="r", ls=":", lw=1)
    axes[2].axvline(shortest * 1e3, color="r", ls=":", lw=1, label=f"shortest T_F at {LIMIT:g} V: {shortest * 1e3:.2f} ms")
    axes[1].axhline(0.5, color="r", ls=":", lw=1, label="thesis criterion")
    for ax, label in zip(axes, ["tau", "margin ratio", "peak voltage (V)"]):
        ax.set_xscale("log")
        ax.set_xticks(tf_ms, [f"{t:g}" for t in tf_ms], fontsize=8)
        ax.minorticks_off()
        ax.set_xlabel("focus time T_F (ms)")
        ax.set_ylabel(label)
        ax.legend(frameon=False, fontsize=8)
    fig.suptitle("thesis-al-cc, sinc 18 mm at 24 mm, 9 modes, open loop (kappa = 1): a shorter focus costs voltage "
                 "but tolerates drift better (its envelopes are wider in frequency)", fontsize=10)
    save_figure(fig, "focus_time", dpi=110)
    print(f"shortest T_F within {LIMIT:g} V: {shortest * 1e3:.2f} ms")


if __name__ == "__main__":
    main()
