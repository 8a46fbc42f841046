"""How much feedback a loop may add: tau, margin and peak voltage against the loops' authority.

    python benchmarks/authority.py   # writes benchmarks/results/authority.{json,md,png} (--report-only: redraw)

A loop's command is capped at ``authority`` times its mode's planned drive at that moment
(:attr:`modalctl.options.LoopOptions.authority`). Too little and a detuned mode, which answers its carrier
several times less, cannot be brought back; too much and noise or a misread mode gets more
voltage. Five structures and shapes, each on a perfect truth (sensor noise only), with the
resonances 1, 2 and 3% off (damping +20%), and with a 1 N s/m finger at the focus; SNR 40 dB,
DAC 500 kHz, PI loops at 20 kHz, one shot (closed loop) per case; open loop beside.
"""

from __future__ import annotations

import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from common import main_or_report, save_figure, write_json, write_markdown  # noqa: E402

from modalctl.experiments.executor import LocalExecutor  # noqa: E402
from modalctl.experiments.sweep import Case, run_case  # noqa: E402
from modalctl.options import LoopOptions  # noqa: E402

AUTHORITIES = (0.25, 0.5, 1.0, 2.0, 4.0)
EXPERIMENTS = {  # label: (scene, shape, params, focus time, points, modes)
    "al-cc sinc 18 mm @ 24 mm": ("thesis-al-cc", "sinc", (("center", "24mm"), ("width", "18mm")), 25e-3, 211, None),
    "al-cc bump 25 mm @ -24 mm": ("thesis-al-cc", "bump", (("center", "-24mm"), ("width", "25mm")), 25e-3, 211, None),
    "al-ff sinc 18 mm @ 0 mm": ("thesis-al-ff", "sinc", (("center", "0mm"), ("width", "18mm")), 25e-3, None, None),
    "plate gaussian 30 mm @ (20, 10) mm": ("plate-glass", "gaussian", (("center", "20mm,10mm"), ("width", "30mm")),
                                           20e-3, None, None),
    "rython sinc 20 mm @ 19 mm": ("thesis-rython-pp", "sinc", (("center", "19mm"), ("width", "20mm")), 25e-3, None, 13),
}
TRUTHS = {  # label: (drift, damping error, finger N s/m)
    "perfect": (0.0, 0.0, 0.0), "drift 1%": (0.01, 0.2, 0.0), "drift 2%": (0.02, 0.2, 0.0),
    "drift 3%": (0.03, 0.2, 0.0), "finger 1 N s/m": (0.0, 0.0, 1.0),
}


def cases():
    """(experiment, truth, authority or None for open loop, Case)."""
    for name, (scene, shape, params, tf, points, modes) in EXPERIMENTS.items():
        for truth, (drift, damping, finger) in TRUTHS.items():
            base = Case(scene=scene, shape=shape, params=params, focus_time=tf, method="open", drift=drift,
                        damping_error=damping, finger=finger, modes=modes, points=points)
            yield name, truth, None, base
            for a in AUTHORITIES:
                yield name, truth, a, Case(**{**base.__dict__, "method": "closed", "authority": a, "controller": "pi"})


def main() -> None:
    jobs = list(cases())
    start = time.perf_counter()
    results = LocalExecutor().map(run_case, [case for *_, case in jobs], progress=True)
    wall = time.perf_counter() - start
    rows = [{"experiment": e, "truth": t, "authority": a, "tau": r["tau"], "margin_ratio": r["margin_ratio"],
             "peak_voltage": r["peak_voltage"], "state": r["state"]} for (e, t, a, _), r in zip(jobs, results)]
    summary = {}
    for a in AUTHORITIES:
        mine = [r for r in rows if r["authority"] == a]
        best = [max(s["tau"] for s in rows if s["authority"] is not None and s["experiment"] == r["experiment"]
                    and s["truth"] == r["truth"]) for r in mine]
        opened = [next(s for s in rows if s["authority"] is None and s["experiment"] == r["experiment"]
                       and s["truth"] == r["truth"]) for r in mine]
        summary[str(a)] = {
            "median_tau": float(np.median([r["tau"] for r in mine])),
            "worst_loss_to_best": float(max(b - r["tau"] for r, b in zip(mine, best))),
            "within_0_01_of_best": int(sum(r["tau"] >= b - 0.01 for r, b in zip(mine, best))),
            "median_peak_over_open": float(np.median([r["peak_voltage"] / o["peak_voltage"]
                                                      for r, o in zip(mine, opened)])),
            "max_peak_over_open": float(max(r["peak_voltage"] / o["peak_voltage"] for r, o in zip(mine, opened))),
            "faults": int(sum(r["state"] == "error" for r in mine))}
    data = {"authorities": AUTHORITIES, "rows": rows, "summary": summary, "cases": len(rows), "wall_seconds": wall}
    report(data, write_json("authority", data))


def report(data: dict, path) -> None:
    rows, summary = data["rows"], data["summary"]
    authorities = data["authorities"]
    cell = lambda r: f"{r['tau']:.3f} ({r['peak_voltage']:.3g} V)"  # noqa: E731
    md = ["# Feedback authority: tau and peak voltage against how much a loop may add", "",
          "Command: `python benchmarks/authority.py`. A loop's command is capped at the authority times its "
          "mode's planned drive at that moment. SNR 40 dB on every truth; drifts with damping +20%; the finger "
          "at the shape's centre. DAC 500 kHz, PI loops at 20 kHz. tau (peak voltage) measured as `modalctl run` measures (the simulated vibrometer over the whole shot, its noise included).",
          "", "| experiment | truth | open loop | " + " | ".join(f"authority {a:g}" for a in authorities) + " |",
          "|---|---|---|" + "---|" * len(authorities)]
    for e in dict.fromkeys(r["experiment"] for r in rows):
        for t in dict.fromkeys(r["truth"] for r in rows):
            mine = {r["authority"]: r for r in rows if r["experiment"] == e and r["truth"] == t}
            md.append(f"| {e} | {t} | {cell(mine[None])} | " + " | ".join(cell(mine[a]) for a in authorities) + " |")
    md += ["", "| authority | median tau | within 0.01 of the best authority | worst loss to the best | "
           "peak voltage over open loop: median (max) | faults |", "|---|---|---|---|---|---|"]
    n = len(rows) // (len(authorities) + 1)
    md += [f"| {a:g} | {s['median_tau']:.3f} | {s['within_0_01_of_best']} of {n} | {s['worst_loss_to_best']:.3f} | "
           f"{s['median_peak_over_open']:.2f} ({s['max_peak_over_open']:.2f}) | {s['faults']} |"
           for a, s in ((a, summary[str(a)]) for a in authorities)]
    md += ["", f"{data['cases']} cases in {data['wall_seconds']:.0f} s on the local process pool.", ""]
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8))
    experiments, truths = dict.fromkeys(r["experiment"] for r in rows), dict.fromkeys(r["truth"] for r in rows)
    for e, color in zip(experiments, plt.rcParams["axes.prop_cycle"].by_key()["color"]):
        for t, marker in zip(truths, "os^vD"):
            mine = [r for r in rows if r["experiment"] == e and r["truth"] == t and r["authority"] is not None]
            opened = next(r for r in rows if r["experiment"] == e and r["truth"] == t and r["authority"] is None)
            axes[0].plot(authorities, [r["tau"] for r in mine], marker=marker, color=color, lw=0.8, ms=4)
            axes[1].plot(authorities, [r["peak_voltage"] / opened["peak_voltage"] for r in mine], marker=marker,
                         color=color, lw=0.8, ms=4)
    for ax in axes:
        ax.set_xscale("log")
        ax.minorticks_off()
        ax.set_xticks(authorities, [f"{a:g}" for a in authorities])
        ax.axvline(LoopOptions.authority, color="k", lw=0.7, ls="--")
        ax.set_xlabel(f"authority (feedback over planned drive; dashed: the default, {LoopOptions.authority:g})")
    axes[0].set(ylabel="tau on the truth", title="tau, one line per experiment and truth")
    axes[1].set(ylabel="peak voltage / open loop's", title="what the feedback adds to the peak voltage")
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    axes[0].legend(handles=[plt.Line2D([], [], color="k", marker=m, lw=0, label=t) for t, m in zip(truths, "os^vD")],
                   fontsize=8, loc="lower right")
    axes[1].legend(handles=[plt.Line2D([], [], color=c, lw=2, label=e) for e, c in zip(experiments, colors)],
                   fontsize=8, loc="upper left")
    save_figure(fig, "authority")
    write_markdown("authority", md, path)


if __name__ == "__main__":
    main_or_report("authority", main, report)
