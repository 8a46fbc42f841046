"""Actuator saturation: tau and peak voltage against the amplifiers' rails, two supervisors.

    python benchmarks/saturation.py   # writes benchmarks/results/saturation.{json,md,png}

The thesis's sinc 18 mm at 24 mm (T_F 25 ms) on a truth with every resonance +1% or +3%, damping
+20% and 40 dB of sensor noise, DAC 500 kHz, PI loops at 10 kHz. The amplifiers clip at the rails,
set at a multiple of the feed-forward's own peak (the plan must fit; the loops get what is left),
and the supervisor keeps the feedback within them: :class:`modalctl.loops.supervisor.Supervisor` from
each DAC sample's voltage (exact), beside the bound it used before (the feed-forward's peak over
the period and the next, plus the sum of the phasors' magnitudes: true whatever the carriers'
phases, so it holds the loops back where the phases would have left room). Open loop and the
unlimited closed loop for reference; three noise seeds each.
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from common import command_line, save_figure, target, write_json, write_markdown  # noqa: E402

import modalctl.loops.shot  # noqa: E402
from modalctl.experiments.focus import Bench, run_focus  # noqa: E402
from modalctl.hil.scenario import Perturbation, perturb  # noqa: E402
from modalctl.loops.supervisor import Supervisor  # noqa: E402
from modalctl.model.scenes import load_scene  # noqa: E402
from modalctl.options import THESIS_PLAN, LoopOptions  # noqa: E402
from modalctl.plan.decompose import decompose  # noqa: E402
from modalctl.plan.planner import plan  # noqa: E402

RAILS = (1.02, 1.05, 1.1, 1.2, 1.5)  # times the feed-forward's peak
DRIFTS = (0.01, 0.03)
SEEDS = (0, 1, 2)
RATE, FS = 10e3, 500e3


class PhaseFreeSupervisor(Supervisor):
    """The supervisor's former limit: the largest factor (by bisection) for which the phase-free
    bounds fit: ``F_c + sum_k max(|P_old|, |P_new|)`` volts over the period and the next."""

    def _largest(self, old, new, played):
        room = self.room[min(played, self.room.shape[0] - 1), :, 0]
        low, high = 0.0, 1.0
        for _ in range(30):
            mid = 0.5 * (low + high)
            fits = not np.count_nonzero(self.gains @ np.maximum(np.abs(old), mid * np.abs(new)) > room)
            low, high = (mid, high) if fits else (low, mid)
        return low


def shot_row(truth, shot, shape, rail: float | None, method: str, seed: int) -> dict:
    """One shot: ``method`` is open, exact (the supervisor) or bound (the phase-free bound)."""
    modalctl.loops.shot.Supervisor = PhaseFreeSupervisor if method == "bound" else Supervisor
    try:
        r = run_focus(truth, shot, shape, LoopOptions(control_rate=RATE, controller="pi"), Bench(voltage_limit=rail, seed=seed),
                      closed=method != "open")
    finally:
        modalctl.loops.shot.Supervisor = Supervisor
    return {"tau": r.tau, "margin_ratio": r.margin_ratio, "peak_voltage": r.peak_voltage, "clipped": int(r.clipped),
            "limited_periods": int(r.result.limited)}


def main() -> None:
    import warnings

    warnings.simplefilter("ignore")
    model = load_scene("thesis-al-cc", 211)
    shape = target(model, "sinc", width="18mm", center="24mm")
    shot = plan(decompose(model, shape, "auto"), 0.025, THESIS_PLAN.but(sample_rate=FS))
    peak = float(np.abs(shot.voltages()).max())
    rows = []
    for drift in DRIFTS:
        truth = perturb(model, Perturbation(drift=drift, damping_error=0.2))
        for rail in (None, *RAILS):
            for method in ("open", "bound", "exact") if rail else ("open", "exact"):
                runs = [shot_row(truth, shot, shape, rail and rail * peak, method, seed) for seed in SEEDS]
                row = {"drift": drift, "rail": rail, "rail_v": rail and rail * peak, "method": method,
                       **{key: float(np.median([r[key] for r in runs])) for key in runs[0]},
                       "tau_min": min(r["tau"] for r in runs), "tau_max": max(r["tau"] for r in runs)}
                rows.append(row)
                print(f"drift {drift:.0%} rails {rail or 'none'}: {method:5} tau {row['tau']:.3f} "
                      f"peak {row['peak_voltage']:.2f} V clipped {row['clipped']:.0f}")
    path = write_json("saturation", {"feedforward_peak_v": peak, "control_rate_hz": RATE, "rows": rows})
    fig, axes = plt.subplots(1, len(DRIFTS), figsize=(11, 4.2), sharey=True)
    for ax, drift in zip(axes, DRIFTS):
        mine = [r for r in rows if r["drift"] == drift]
        unlimited = next(r["tau"] for r in mine if r["rail"] is None and r["method"] == "exact")
        for method, label, style in (("exact", "closed, supervisor from the samples", "o-"),
                                     ("bound", "closed, phase-free bound", "s--"), ("open", "open loop", "^:")):
            line = [r for r in mine if r["method"] == method and r["rail"] is not None]
            x = [r["rail"] for r in line]
            err = np.array([[r["tau"] - r["tau_min"], r["tau_max"] - r["tau"]] for r in line]).T
            ax.errorbar(x, [r["tau"] for r in line], yerr=err, fmt=style, capsize=3, label=label)
        ax.axhline(unlimited, color="k", lw=0.8, ls=":", label="closed, no rails")
        ax.set(xscale="log", xlabel="rails / feed-forward peak", title=f"resonances +{drift:.0%}, damping +20%")
        ax.set_xticks(RAILS, [f"{r:g}" for r in RAILS])
        ax.minorticks_off()
    axes[0].set_ylabel("tau on the truth (median of 3 seeds)")
    axes[0].legend(fontsize=8)
    fig.suptitle("Actuator saturation: the feedback within the rails (al-cc sinc 18 mm, 10 kHz loops)")
    save_figure(fig, "saturation")
    md = ["# Actuator saturation: tau against the rails, two supervisors", "",
          "Command: `python benchmarks/saturation.py`. sinc 18 mm at 24 mm, truth +1% or +3% / +20% damping / "
          f"40 dB, DAC 500 kHz, loops at {RATE / 1e3:g} kHz; rails (the amplifiers clip there, the supervisor "
          f"keeps the feedback within them) as multiples of the feed-forward's peak, {peak:.2f} V. Medians of "
          f"{len(SEEDS)} noise seeds.", "",
          "| drift | rails / ff peak | open tau | closed tau, phase-free bound | closed tau, from the samples "
          "| peak V (from the samples) | clipped samples | periods held back |", "|---|---|---|---|---|---|---|---|"]
    for drift in DRIFTS:
        for rail in (None, *RAILS):
            cell = {r["method"]: r for r in rows if r["drift"] == drift and r["rail"] == rail}
            bound = f"{cell['bound']['tau']:.3f}" if "bound" in cell else "-"
            exact = cell["exact"]
            md.append(f"| {drift:.0%} | {rail or 'none'} | {cell['open']['tau']:.3f} | {bound} | {exact['tau']:.3f} | "
                      f"{exact['peak_voltage']:.2f} | {exact['clipped']:.0f} | {exact['limited_periods']:.0f} |")
    md += ["", "The supervisor scales each period's feedback by the largest factor that keeps every DAC sample "
           "of the period it plays in, and of the next (held or dropped to zero), within the rails "
           "(`modalctl/supervisor.py`); the bound beside it is the one it used before, true whatever the "
           "carriers' phases. Clipped samples: the amplifiers' count of samples beyond the rails (none means "
           "the supervisor kept them).", ""]
    write_markdown("saturation", md, path)


if __name__ == "__main__":
    command_line()
    main()
