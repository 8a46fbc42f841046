"""Speed against accuracy in closed loop: tau against the control rate and the compute per period.

    python benchmarks/control_rate.py   # writes benchmarks/results/control_rate.{json,md,png} (--report-only: redraw)

The thesis's sinc 18 mm at 24 mm (T_F 25 ms, kappa = 1) on a truth with every resonance +1%, damping
+20% and 40 dB of sensor noise, DAC 500 kHz; the loops at 2-50 kHz (each redesigned for its rate:
lock-in corners and crossovers follow it), 7.8125 kHz being 64 DAC samples a period. For each rate,
three noise seeds: tau, the runtime's compute per period (median, the board excluded) and the real-
time factors (wall time over played time; below 1 is faster than real time) of the loop with the
emulated board, of the shot (the truth's answer at every DAC sample, the lock-in, the loop and its
log on disk, the records) and of the whole shot (the emulator's set-up before it too), first with
the C allocator as it comes, then with memory kept as ``modalctl run`` keeps it
(:mod:`modalctl.loops.realtime`). The peer, beside each shot in the same run: python-control's
``forced_response`` of the truth alone on the shot's voltages (which also checks the board's records
of the truth's answer). Each shot by the board's period map (:mod:`modalctl.hil.lifted`, the
default) and sample by sample; both must measure the same tau (checked here to 1e-9). Each timing is
the median of ``REPEATS`` plays of the same shot (this shared machine moves a single one by up to
30%). Open loop for reference.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import control  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from common import (  # noqa: E402
    main_or_report,
    median_seconds,
    read_json,
    save_figure,
    state_space,
    target,
    write_json,
    write_markdown,
)

from modalctl.experiments.focus import Bench, run_focus  # noqa: E402
from modalctl.hil.scenario import Perturbation, perturb  # noqa: E402
from modalctl.loops.realtime import keep_memory  # noqa: E402
from modalctl.model.scenes import load_scene  # noqa: E402
from modalctl.options import THESIS_PLAN, LoopOptions  # noqa: E402
from modalctl.plan.decompose import decompose  # noqa: E402
from modalctl.plan.planner import plan  # noqa: E402

RATES = (2e3, 5e3, 500e3 / 64, 10e3, 20e3, 50e3)
SEEDS = (0, 1, 2)
FS = 500e3
REPEATS = 5


TIMINGS = ("real_time_factor", "shot_real_time_factor", "run_real_time_factor")


def timed(truth, shot, shape, lifted: bool, logs: Path, discrete=None) -> tuple[dict, dict]:
    """Every (rate, seed)'s shot played ``REPEATS`` times, the rounds interleaved over the rates and seeds (a burst of
    load on this shared machine then hits them all alike), each with its log of every period in ``logs`` (as
    ``modalctl run`` keeps it); every play must measure the same tau. Returns, for each (rate, seed), its first
    play and the median of each timing (the real-time factors of :class:`~modalctl.experiments.focus.ClosedShot`, the
    set-up's seconds); and for each rate, with ``discrete`` (the truth's zero-order-hold state space), the
    median real-time factor of python-control simulating the truth alone on the voltages of its seed-0 shot,
    timed in each round beside the plays."""
    keys = [(rate, seed) for rate in RATES for seed in SEEDS]
    first, times = {}, {key: {name: [] for name in (*TIMINGS, "configure_seconds")} for key in keys}
    peers = {rate: [] for rate in RATES}
    for _ in range(REPEATS):
        for rate, seed in keys:
            play = run_focus(truth, shot, shape, LoopOptions(control_rate=rate, controller="pi"), Bench(seed=seed, lifted=lifted),
                             log=logs / f"{rate:g}-{seed}")
            if first.setdefault((rate, seed), play).tau != play.tau:
                raise AssertionError(f"{rate:g} Hz seed {seed}: the same shot measured different tau")
            for name in TIMINGS:
                times[rate, seed][name].append(getattr(play, name))
            times[rate, seed]["configure_seconds"].append(play.result.configure_seconds)
            if discrete is not None and seed == SEEDS[0]:
                applied = play.board.applied
                instants = np.arange(applied.shape[1]) / FS
                peers[rate].append(median_seconds(lambda: control.forced_response(discrete, instants, applied), 1)
                                   / play.duration)
    medians = {key: (first[key], {name: float(np.median(v)) for name, v in times[key].items()}) for key in keys}
    return medians, {rate: float(np.median(v)) for rate, v in peers.items() if v}


def agreement(discrete, play) -> float:
    """The largest difference between python-control's velocities of the truth alone (``discrete``:
    its zero-order-hold form) on the voltages ``play``'s board applied and the board's records of
    them, relative to their peak."""
    applied, velocity = play.board.applied, play.board.velocity
    theirs = control.forced_response(discrete, np.arange(applied.shape[1]) / FS, applied).outputs
    return float(np.abs(theirs - velocity).max() / np.abs(velocity).max())


def main() -> None:
    import warnings

    warnings.simplefilter("ignore")
    model = load_scene("thesis-al-cc", 211)
    shape = target(model, "sinc", width="18mm", center="24mm")
    shot = plan(decompose(model, shape, "auto"), 0.025, THESIS_PLAN.but(sample_rate=FS))
    truth = perturb(model, Perturbation(drift=0.01, damping_error=0.2))
    open_tau = [run_focus(truth, shot, shape, bench=Bench(seed=s), closed=False).tau for s in SEEDS]
    discrete = control.sample_system(state_space(truth), 1 / FS, "zoh")
    # the C allocator as it comes first (keep_memory lasts for the rest of the process), then as
    # modalctl run and sweep set it
    with tempfile.TemporaryDirectory() as logs:
        default, _ = timed(truth, shot, shape, True, Path(logs))
        kept = keep_memory()
        lifted, peer = timed(truth, shot, shape, True, Path(logs), discrete)
        by_samples, _ = timed(truth, shot, shape, False, Path(logs))
    rows = []
    for rate in RATES:
        for seed in SEEDS:
            (r, times), (sampled, samples_times) = lifted[rate, seed], by_samples[rate, seed]
            if abs(r.tau - sampled.tau) > 1e-9:
                raise AssertionError(f"period map and samples disagree: tau {r.tau} against {sampled.tau}")
            peer_difference = agreement(discrete, r)
            if peer_difference > 1e-8:
                raise AssertionError(f"the board's records and python-control differ by {peer_difference:.1e}")
            rows.append({"rate_hz": rate, "seed": seed, "tau": r.tau, "margin_ratio": r.margin_ratio,
                         "step_seconds": float(np.median(r.result.step_seconds)),
                         "period_seconds": times["real_time_factor"] / rate, **times,
                         "samples_real_time_factor": samples_times["real_time_factor"],
                         "samples_shot_real_time_factor": samples_times["shot_real_time_factor"],
                         "peer_real_time_factor": peer[rate], "peer_relative_difference": peer_difference,
                         "default_shot_real_time_factor": default[rate, seed][1]["shot_real_time_factor"],
                         "default_run_real_time_factor": default[rate, seed][1]["run_real_time_factor"],
                         "crossover_hz": [float(r.design.crossover_hz.min()), float(r.design.crossover_hz.max())]})
            print(f"{rate / 1e3:4g} kHz seed {seed}: tau {r.tau:.3f}, {1e6 * rows[-1]['step_seconds']:.0f} us/period, "
                  f"loop x{times['real_time_factor']:.2f} real time "
                  f"(by samples x{samples_times['real_time_factor']:.2f}), shot x{times['run_real_time_factor']:.2f}, "
                  f"whole x{times['shot_real_time_factor']:.2f} (x{samples_times['shot_real_time_factor']:.2f}), "
                  f"python-control's truth alone x{peer[rate]:.2f}")
    summary = []
    for rate in RATES:
        mine = [r for r in rows if r["rate_hz"] == rate]
        summary.append({"rate_hz": rate, "tau_median": float(np.median([r["tau"] for r in mine])),
                        "tau_min": float(min(r["tau"] for r in mine)), "tau_max": float(max(r["tau"] for r in mine)),
                        "step_seconds": float(np.median([r["step_seconds"] for r in mine])),
                        "period_seconds": float(np.median([r["period_seconds"] for r in mine])),
                        **{key: float(np.median([r[key] for r in mine])) for key in
                           ("real_time_factor", "shot_real_time_factor", "samples_real_time_factor",
                            "samples_shot_real_time_factor", "run_real_time_factor", "configure_seconds",
                            "peer_real_time_factor", "default_shot_real_time_factor",
                            "default_run_real_time_factor")},
                        "crossover_hz": mine[0]["crossover_hz"]})
    difference = max(r["peer_relative_difference"] for r in rows)
    path = write_json("control_rate", {"rows": rows, "summary": summary, "open_loop_tau": open_tau,
                                       "records_against_python_control": difference, "memory_kept": kept})
    report(read_json("control_rate")[0], path)


def report(data: dict, path) -> None:
    """The chart and the tables of a run's JSON ``data``."""
    summary, open_tau, kept = data["summary"], data["open_loop_tau"], data["memory_kept"]
    difference, load = data["records_against_python_control"], data["machine"]["load_average_1_5_15_min"]
    fig, (left, middle, right) = plt.subplots(1, 3, figsize=(15, 4.4))
    rates = np.array([s["rate_hz"] for s in summary]) / 1e3
    for ax, x, label in ((left, rates, "control rate (kHz)"),
                         (right, [s["step_seconds"] * s["rate_hz"] for s in summary],
                          "runtime's compute per second of control (s)")):
        y = np.array([s["tau_median"] for s in summary])
        err = np.array([[s["tau_median"] - s["tau_min"], s["tau_max"] - s["tau_median"]] for s in summary]).T
        ax.errorbar(x, y, yerr=err, fmt="o-", capsize=3, label="closed loop (3 noise seeds)")
        ax.axhline(np.median(open_tau), color="C3", ls="--", label="open loop")
        ax.axhline(0.95, color="k", ls=":", lw=0.8)
        ax.set(xlabel=label, ylabel="tau on the truth", xscale="log")
    for name, key, style in (("the loop with the emulated board", "real_time_factor", "o-"),
                             ("the shot (activation, loop, log, records)", "run_real_time_factor", "s-"),
                             ("the whole shot (its set-up too)", "shot_real_time_factor", "^-"),
                             ("the whole shot, by samples", "samples_shot_real_time_factor", "v:"),
                             ("python-control: the truth alone, open loop", "peer_real_time_factor", "x--")):
        middle.plot(rates, [s[key] for s in summary], style, label=name)
    middle.axhline(1.0, color="k", lw=0.8)
    middle.text(rates[-1], 0.9, "real time", fontsize=8, ha="right", va="top")
    middle.set(xlabel="control rate (kHz)", ylabel="wall time / played time", xscale="log", yscale="log",
               ylim=(0.1, 100))  # room above for the legend
    for ax, x in ((left, rates), (middle, rates), (right, [s["step_seconds"] * s["rate_hz"] for s in summary])):
        ax.minorticks_off()
        ax.set_xticks(x, [f"{v:.3g}" for v in x], rotation=45)
    left.set_title("tau against the loop rate")
    middle.set_title("speed: below the line is faster than real time", fontsize=10)
    right.set_title("tau against the runtime's compute load")
    left.legend(fontsize=8)
    middle.set_yticks([0.1, 0.2, 0.5, 1, 2, 5, 10], ["0.1", "0.2", "0.5", "1", "2", "5", "10"])
    middle.legend(fontsize=7, loc="upper left")
    save_figure(fig, "control_rate")
    memory = "kept (modalctl.loops.realtime.keep_memory)" if kept else "as it came (not glibc: keep_memory does nothing)"
    md = ["# Closed loop: tau against control rate and compute", "",
          "Command: `python benchmarks/control_rate.py`. sinc 18 mm at 24 mm, truth +1% / +20% damping / 40 dB, "
          f"DAC 500 kHz, shot 29 ms (ring-down included). Open loop tau {np.median(open_tau):.3f}. Medians of the "
          f"3 seeds, each timing the median of {REPEATS} plays of the shot; wall time over played time, below 1 is "
          "faster than real time.", "",
          "## Accuracy and the loop", "",
          "| rate (kHz) | tau median (min-max, 3 seeds) | crossovers (Hz) "
          "| us a period: whole loop (runtime's compute) | loop wall / real time: period map (by samples) |",
          "|---|---|---|---|---|"]
    md += [f"| {s['rate_hz'] / 1e3:g} | {s['tau_median']:.3f} ({s['tau_min']:.3f}-{s['tau_max']:.3f}) | "
           f"{s['crossover_hz'][0]:.0f}-{s['crossover_hz'][1]:.0f} | {1e6 * s['period_seconds']:.0f} "
           f"({1e6 * s['step_seconds']:.0f}) | "
           f"{s['real_time_factor']:.2f} ({s['samples_real_time_factor']:.2f}) |" for s in summary]
    md += ["", "The loop's wall time includes the emulated board (the truth's answer to the commands at 500 kHz, "
           "lock-in, modulation) and the runtime, one Python pass per period (a period's wall time less the "
           "runtime's compute is the board's emulation and the runtime's bookkeeping). Period map and samples "
           "measure the same tau (to 1e-9, checked in the run).", "",
           "## The whole shot against real time", "",
           "| rate (kHz) | shot | emulator's set-up (ms) "
          f"| whole shot with set-up: memory {'kept' if kept else 'as it came'} "
           "(by samples) | whole shot, the C allocator as it comes | python-control, the truth alone |",
           "|---|---|---|---|---|---|"]
    md += [f"| {s['rate_hz'] / 1e3:g} | {s['run_real_time_factor']:.2f} | {1e3 * s['configure_seconds']:.1f} | "
           f"{s['shot_real_time_factor']:.2f} ({s['samples_shot_real_time_factor']:.2f}) | "
           f"{s['default_shot_real_time_factor']:.2f} | {s['peer_real_time_factor']:.2f} |" for s in summary]
    md += ["", "The shot: its activation (the truth's answer to the feed-forward at every DAC sample, this shot's "
           "noise, and the readings of both, one lock-in pass), the loop with its log of every period on disk "
           "(as `modalctl run` keeps it), and the records of every DAC sample: all of the shot's physics. "
           "The whole shot adds the emulator's set-up before it (ros2_control's configure: the period map and "
           "the lock-in's matrices, made from the plan's carriers and rates; by samples, the lock-in alone). "
           "The loops' design is in none of them. The C allocator: "
           f"{memory} for every column but the one measured first, before it was set, in the same run: glibc gives "
           "large freed arrays back to the system, and the next shot's first write to each page faults (~1 ms a "
           "megabyte here). The peer, timed in the same run beside each shot: python-control's `forced_response` "
           "of the truth alone (21 modes, its zero-order-hold discretization, no loop, no lock-in) on the "
           f"voltages the shot applied; its velocities agree with the board's records to {difference:.1e} of "
           "their peak. Machine load average when written (1, 5, 15 min; the run itself counts about one): "
           f"{', '.join(f'{x:.2f}' for x in load)}.",
           ""]
    write_markdown("control_rate", md, path)


if __name__ == "__main__":
    main_or_report("control_rate", main, report)
