"""Open loop against per-mode feedback on the thesis-al-cc experiments, on a perturbed truth.

    python benchmarks/closed_loop.py   # writes benchmarks/results/closed_loop.{json,md,png}

Truth: every resonance +1%, damping +20%, sensor noise 40 dB below the focus peak. Each
experiment (the thesis's shapes, centres and mode counts, T_F 25 ms, kappa = 1 as the thesis ran
it) is planned on the model and played twice on the HIL at 500 kHz: feed-forward alone, and with
the per-mode PI loops of `modalctl.control` at 20 kHz (model-following reference through the
lock-in). Also the thesis's margin case with the optimizer's plan. tau and the margin ratio are
measured on the truth's whole field.
"""

from __future__ import annotations

import time
import warnings

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from common import RESULTS, target, save_figure, write_json  # noqa: E402
from modalctl.decompose import decompose  # noqa: E402
from modalctl.hil.closed import run_focus  # noqa: E402
from modalctl.hil.scenario import Perturbation, perturb  # noqa: E402
from modalctl.planner import plan  # noqa: E402
from modalctl.scenes import load_scene  # noqa: E402
from thesis_table import experiments  # noqa: E402

TRUTH = Perturbation(drift=0.01, damping_error=0.2)
FS = 500e3


def main() -> None:
    warnings.simplefilter("ignore")
    model = load_scene("thesis-al-cc", 211)
    truth = perturb(model, TRUTH)
    rows = []
    for name, scene, shape_name, params, centres, modes, tf, _ in experiments():
        if scene != "thesis-al-cc":
            continue
        margin = 0.5 if "margin" in name else None
        for centre in centres:
            shape = target(model, shape_name, **params, center=f"{centre}m")
            shot = plan(decompose(model, shape, modes or "auto"), tf, margin=margin, sample_rate=FS)
            start = time.perf_counter()
            results = {kind: run_focus(truth, shot, shape, closed=kind == "closed", snr_db=40.0)
                       for kind in ("open", "closed")}
            seconds = time.perf_counter() - start
            row = {"experiment": f"{name} @ {centre * 1e3:g} mm", "modes": len(shot.modes),
                   "shot_seconds": seconds / 2, "simulated_seconds": shot.duration}
            for kind, r in results.items():
                row |= {f"tau_{kind}": r.tau, f"margin_{kind}": r.margin_ratio, f"peak_voltage_{kind}": r.peak_voltage}
            rows.append(row)
            print(f"{row['experiment']:34s} tau open {row['tau_open']:.3f} closed {row['tau_closed']:.3f}  "
                  f"margin {row['margin_open']:.2f} / {row['margin_closed']:.2f}")
    data = {"truth": TRUTH.describe() + ", SNR 40 dB", "rows": rows,
            "median_tau_open": float(np.median([r["tau_open"] for r in rows])),
            "median_tau_closed": float(np.median([r["tau_closed"] for r in rows]))}
    path = write_json("closed_loop", data)
    md = ["# Open loop against per-mode feedback, thesis-al-cc, perturbed truth", "",
          f"Command: `python benchmarks/closed_loop.py`. Truth: {data['truth']}; plant 500 kHz, loops 20 kHz. "
          "tau and the margin ratio on the truth's whole field (21 modes).", "",
          "| experiment | modes | tau open | tau closed | margin open | margin closed | peak V open | peak V closed |",
          "|---|---|---|---|---|---|---|---|"]
    md += [f"| {r['experiment']} | {r['modes']} | {r['tau_open']:.3f} | {r['tau_closed']:.3f} | {r['margin_open']:.2f} | "
           f"{r['margin_closed']:.2f} | {r['peak_voltage_open']:.1f} | {r['peak_voltage_closed']:.1f} |" for r in rows]
    md += ["", f"Median tau: open {data['median_tau_open']:.3f}, closed {data['median_tau_closed']:.3f}. "
           f"One shot simulates in {np.median([r['shot_seconds'] for r in rows]):.1f} s (median) for "
           f"{1e3 * rows[0]['simulated_seconds']:.0f} ms of real time: the closed-loop HIL is not yet faster than "
           "real time.", ""]
    (RESULTS / "closed_loop.md").write_text("\n".join(md))
    fig, ax = plt.subplots(figsize=(12, 4.5))
    x = np.arange(len(rows))
    ax.bar(x - 0.2, [r["tau_open"] for r in rows], 0.4, label="open loop")
    ax.bar(x + 0.2, [r["tau_closed"] for r in rows], 0.4, label="closed loop")
    ax.axhline(0.95, color="k", lw=0.7, ls="--")
    ax.set_xticks(x, [r["experiment"] for r in rows], rotation=70, fontsize=7)
    ax.set(ylabel="tau on the truth", ylim=(0, 1.1), title=f"thesis-al-cc experiments, truth: {data['truth']}")
    ax.legend()
    save_figure(fig, "closed_loop")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
