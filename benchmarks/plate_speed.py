"""Haptic surfaces at the beam's speed: each stage of a shot's command, from the beam to a tablet panel.

    python benchmarks/plate_speed.py                  # commands, then the cost curve (about 25 min)
    python benchmarks/plate_speed.py --part commands  # one part: commands, curve
    python benchmarks/plate_speed.py --no-baseline    # without the previous commit's numbers
    python benchmarks/plate_speed.py --report-only    # redraw from results/plate_speed.json

writes benchmarks/results/plate_speed.{json,md,png}.

1. ``commands``: ``modalctl run`` as a user types it (a bump at (-20, 5) mm, T_F 25 ms; the sinc
   on the beam) on thesis-al-cc, plate-glass, plate-glass-clamped, panel-rounded and the tablet
   panel (210 x 150 x 0.7 mm glass, clamped, eight 14 x 10 mm patches off its mirror axes,
   ``common.tablet_arguments``, ``model fe --band 20kHz``, a 20 mm bump), open loop, closed loop with 1% drift and 40 dB, and closed loop with a finger
   and the touch controller: each command in a fresh process, its wall time (median of
   ``REPEATS``, nothing watching) and peak memory (one more run, its process tree sampled), and its
   stages from its ``metrics.json`` (import and start-up, model, growth, plan, play, scan, writing
   the field, pictures). Beside it, the same commands on
   the commit before this work (``BASELINE``), installed in a virtual environment of its own, in the
   same run (``--tau-target 0.95`` there on the finite-element scenes: at the default target it
   refused them).
2. ``curve``: the cost as the work grows: modes kept (64 to 254 on the tablet panel, ``--modes N``),
   grid points (panel-rounded from 31 x 18 to 241 x 141) and shot length (T_F 10 to 100 ms), each
   stage's time and the command's peak memory, and the fitted log-log slope of each (1: linear).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from common import RESULTS, read_json, speed_probe, tablet_arguments, write_json, write_markdown

ROOT = Path(__file__).resolve().parents[1]
PYTHON = sys.executable
BASELINE = "a5e4a24"  # main before issues 35 and 36
REPEATS = 3
TIMEOUT_S = 240  # per command
TABLET_TIMEOUT_S = 120  # per tablet command: twice the target (60 s)
#: solved once per geometry (the name carries a digest of its arguments), not committed (64 MB)
TABLET = ROOT / "benchmarks" / ".cache" / (
    f"tablet-{hashlib.sha1(' '.join(tablet_arguments('')).encode()).hexdigest()[:8]}.npz")
TABLET_COMMAND = tablet_arguments(TABLET)
BUMP = ["--shape", "bump", "--param", "width=30mm", "--param", "center=-20mm,5mm"]
CASES = {  # scene: (where the model comes from, the shape)
    "thesis-al-cc": (["--scene", "thesis-al-cc"], ["--shape", "sinc", "--param", "width=18mm", "--param", "center=24mm"]),
    "plate-glass": (["--scene", "plate-glass"], BUMP),
    "plate-glass-clamped": (["--scene", "plate-glass-clamped"], BUMP),
    "panel-rounded": (["--scene", "panel-rounded"], BUMP),
    # the tablet at tau 0.95: at 0.98 the 20 mm bump asks for modes past 20 kHz (0.966 there), about 430 to 30 kHz
    "tablet": (["--model", str(TABLET), "--tau-target", "0.95"],
               ["--shape", "bump", "--param", "width=20mm", "--param", "center=-20mm,5mm"]),
    "tablet-30mm": (["--model", str(TABLET), "--tau-target", "0.95"], BUMP),
}
TARGETS = [  # (what, case/loop, field, at most): the targets
    ("panel open loop, whole command (s)", "panel-rounded/open", "wall_s", 4.0),
    ("panel closed loop, whole command (s)", "panel-rounded/closed", "wall_s", 10.0),
    ("panel plan, open loop (s)", "panel-rounded/open", "plan", 2.0),
    ("panel plan, closed loop (s)", "panel-rounded/closed", "plan", 5.0),
    ("panel loop update, touch controller (us)", "panel-rounded/touch", "step_us", 50.0),
    ("panel run folder, closed loop (MB)", "panel-rounded/closed", "folder_mb", 20.0),
    ("tablet 20 mm bump, open loop (s)", "tablet/open", "wall_s", 60.0),
    ("tablet 20 mm bump, closed loop (s)", "tablet/closed", "wall_s", 60.0),
]
LOOPS = {"open": [], "closed": ["--loop", "closed", "--drift", "1%", "--snr", "40"],
         "touch": ["--loop", "closed", "--drift", "1%", "--snr", "40", "--finger", "1Ns/m", "--controller", "touch"]}
STAGES = ("start-up", "model", "growth", "plan", "play", "scan", "write", "pictures")


def timed(command: list[str], repeats: int = 1, python: str = PYTHON, env: dict | None = None,
          timeout: float = TIMEOUT_S) -> dict:
    """:func:`median_row` of ``repeats`` runs of ``command`` with nothing watching them, and the peak
    memory of one more run, sampled (:func:`measured`'s ``memory``): the sampler's reads of /proc made the
    panel's open loop 4.17-4.39 s against 3.68-3.94 s unwatched (2026-11-29, three each, alternated)."""
    row = median_row([measured(command, python, env, timeout) for _ in range(repeats)])
    sized = measured(command, python, env, timeout, memory=True)
    return {**row, "peak_mb": sized["peak_mb"], "sampled_wall_s": sized["wall_s"]}


def measured(command: list[str], python: str = PYTHON, env: dict | None = None, timeout: float = TIMEOUT_S,
             memory: bool = False) -> dict:
    """Run ``python -c 'modalctl main' command`` in a fresh process: its exit code, wall time (s),
    peak memory (MB) and, when it wrote one, its metrics.json. ``memory``: the peak of the process and
    the children it forks together, sampled every 20 ms (which slows it); else the process's own
    resident peak, which costs nothing to read."""
    out = Path(command[command.index("--out") + 1]) if "--out" in command else None
    code = "import sys; from modalctl.cli import main; sys.exit(main(sys.argv[1:]))"
    start = time.perf_counter()
    errors = tempfile.TemporaryFile()  # a file, not a pipe: a chatty command cannot fill it and stall
    process = subprocess.Popen([python, "-c", code, *command], stdout=subprocess.DEVNULL, stderr=errors,
                               env={**os.environ, **(env or {})}, cwd=tempfile.gettempdir())
    timer = threading.Timer(timeout, process.kill)  # a command past its budget is a result, not a hang
    timer.start()
    tree = _TreeMemory(process.pid) if memory else None  # with its children (the FE's coarse mesh, the pictures)
    _, status, usage = os.wait4(process.pid, 0)
    if tree is not None:
        tree.stop()
    timer.cancel()
    wall = time.perf_counter() - start
    errors.seek(0)
    stderr = errors.read().decode(errors="replace") if wall < timeout else f"killed after {timeout:g} s"
    errors.close()
    row = {"exit": os.waitstatus_to_exitcode(status), "wall_s": wall,
           "peak_mb": max(usage.ru_maxrss / 1024, 0.0 if tree is None else tree.peak_mb)}
    if row["exit"] != 0:
        row["error"] = stderr.strip().splitlines()[-1] if stderr.strip() else "?"
    metrics = out / "metrics.json" if out else None
    if metrics is not None and metrics.is_file() and row["exit"] == 0:
        row["metrics"] = json.loads(metrics.read_text())
        row["folder_mb"] = sum(p.stat().st_size for p in out.iterdir()) / 1e6
    return row


class _TreeMemory(threading.Thread):
    """The largest memory (MB) a process and its descendants held together, their proportional set
    sizes sampled every 20 ms from /proc (ru_maxrss counts the process alone, not the children it
    forks). A run's peak is the larger of this and the process's own ru_maxrss (a peak between two
    samples). Reading smaps_rollup costs the sampler a few per cent of one core."""

    def __init__(self, pid: int):
        super().__init__(daemon=True)
        self.pid, self.peak_mb, self._done = pid, 0.0, threading.Event()
        self.start()

    def run(self) -> None:
        while not self._done.wait(0.02):
            self.peak_mb = max(self.peak_mb, sum(_proportional_kb(p) for p in _tree(self.pid)) / 1024)

    def stop(self) -> None:
        self._done.set()
        self.join()


def _tree(pid: int) -> list[int]:
    found, todo = [], [pid]
    while todo:
        p = todo.pop()
        found.append(p)
        try:
            for task in Path(f"/proc/{p}/task").iterdir():
                todo += [int(c) for c in (task / "children").read_text().split()]
        except OSError:
            pass
    return found


def _proportional_kb(pid: int) -> int:
    """A process's proportional set size (kB): its pages, each shared one divided among its holders
    (a forked child shares its parent's pages: counted twice, resident sizes would overstate)."""
    try:
        for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
            if line.startswith("Pss:"):
                return int(line.split()[1])
    except (OSError, IndexError, ValueError):
        pass
    return 0


def stages(row: dict) -> dict:
    """Seconds per stage from a run's metrics (start-up: the wall time no stage accounts for)."""
    m = row.get("metrics")
    if m is None:
        return {}
    own = m.get("stages_s", {})
    found = {"model": own.get("model_s"), "growth": own.get("growth_s"), "plan": m.get("plan_seconds"),
             "play": m.get("play_seconds"), "scan": m.get("scan_seconds"), "write": own.get("write_fields_s"),
             "pictures": own.get("pictures_wait_s", own.get("pictures_s"))}  # drawn beside the write: what they added
    if found["play"] is None and m.get("sim_seconds") is not None:  # the baseline: play and scan together
        found["play"] = m["sim_seconds"]
    known = sum(v for v in found.values() if v is not None)
    return {"start-up": max(0.0, row["wall_s"] - known), **found}


def median_row(rows: list[dict]) -> dict:
    """The run with the median wall time, the wall time and peak memory medians over ``rows``."""
    ok = [r for r in rows if r["exit"] == 0] or rows
    middle = sorted(ok, key=lambda r: r["wall_s"])[len(ok) // 2]
    return {**middle, "wall_s": float(np.median([r["wall_s"] for r in ok])),
            "peak_mb": float(np.median([r["peak_mb"] for r in ok])), "repeats": len(ok)}


def summary(row: dict) -> dict:
    """What the tables keep of a run."""
    m = row.get("metrics", {})
    loop = m.get("loop") or {}
    return {"exit": row["exit"], "error": row.get("error"), "wall_s": row["wall_s"], "peak_mb": row["peak_mb"],
            "repeats": row.get("repeats", 1), "folder_mb": row.get("folder_mb"), "stages_s": stages(row),
            "tau": m.get("tau"), "margin_ratio": m.get("margin_ratio"), "modes_kept": len(m.get("modes_used", [])),
            "model_modes": (m.get("model") or {}).get("modes"), "grown": (m.get("model") or {}).get("grown"),
            "step_us": None if loop.get("step_seconds_median") is None else 1e6 * loop["step_seconds_median"],
            "step_p99_us": None if loop.get("step_seconds_p99") is None else 1e6 * loop["step_seconds_p99"],
            "real_time_factor": loop.get("real_time_factor")}


def _update(row: dict) -> str:
    """A loop update's median (and 99th percentile) in microseconds, '-' without a loop on the host."""
    if row.get("step_us") is None:
        return "-"
    return _f(row["step_us"], "{:.0f}") + ("" if row.get("step_p99_us") is None else f" ({row['step_p99_us']:.0f})")


def baseline_python() -> str | None:
    """A python whose ``modalctl`` is the commit :data:`BASELINE`, in a virtual environment of its own
    (made once under benchmarks/.cache); None when it cannot be made."""
    where = ROOT / "benchmarks" / ".cache" / f"baseline-{BASELINE}"
    python = where / "venv" / "bin" / "python"
    if python.exists():
        return str(python)
    try:
        if not (where / "src").exists():
            subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(where / "src"), BASELINE],
                           check=True, capture_output=True)
        subprocess.run([PYTHON, "-m", "venv", str(where / "venv")], check=True)
        subprocess.run([str(python), "-m", "pip", "install", "--quiet", "-e", str(where / "src")], check=True)
    except (subprocess.CalledProcessError, OSError) as exc:
        print(f"no baseline: {exc}", file=sys.stderr)
        return None
    return str(python)


def run_commands(baseline: bool, quick: bool) -> dict:
    """Part 1: every case and loop, now and (when asked) on the baseline; the machine's speed
    (``common.speed_probe``) before and after them: a shared machine's pace changes within the hour."""
    before = speed_probe()
    if not TABLET.exists():
        TABLET.parent.mkdir(parents=True, exist_ok=True)
        print("solving the tablet panel once:", " ".join(TABLET_COMMAND), flush=True)
        solved = measured(TABLET_COMMAND, memory=True)
        if solved["exit"] != 0:
            raise SystemExit(f"the tablet panel could not be solved: {solved.get('error')}")
    tablet = timed([*TABLET_COMMAND[:-1], str(TABLET.with_name("tablet-again.npz"))])  # with a warm cache
    old = baseline_python() if baseline else None
    scratch = Path(tempfile.mkdtemp(prefix="plate-speed-"))
    rows = {}
    for case, (model, shape) in CASES.items():
        for loop, extra in LOOPS.items():
            if case.startswith("tablet") and (loop == "touch" or quick):
                continue  # the touch controller's cost is the panel's case
            repeats = 1 if case.startswith("tablet") or quick or loop != "open" else REPEATS  # closed loops: one each
            command = ["run", *model, *shape, "--focus-time", "25ms", *extra, "--out", str(scratch / "run"), "--force",
                       "--quiet"]
            print(f"{case} {loop}: modalctl {' '.join(command)}", flush=True)
            timeout = TABLET_TIMEOUT_S if case.startswith("tablet") else TIMEOUT_S
            now = timed(command, repeats, timeout=timeout)
            rows[f"{case}/{loop}"] = {"now": summary(now)}
            if old is not None and not case.startswith("tablet"):
                then = command + (["--tau-target", "0.95"] if case in ("plate-glass-clamped", "panel-rounded") else [])
                plain = {"PYTHONPATH": ""}  # the baseline's own modalctl, whatever this process was given
                rows[f"{case}/{loop}"]["baseline"] = summary(timed(then, 1, old, plain))  # once: it is the slow one
    shutil.rmtree(scratch, ignore_errors=True)
    return {"cases": rows, "tablet_model": {"wall_s": tablet["wall_s"], "peak_mb": tablet["peak_mb"],
                                             "exit": tablet["exit"], "command": " ".join(TABLET_COMMAND)},
            "baseline": BASELINE if old else None, "speed": {"before": before, "after": speed_probe()}}


def run_curve(quick: bool) -> dict:
    """Part 2: stage times against modes kept, grid points and shot length; fitted slopes."""
    scratch = Path(tempfile.mkdtemp(prefix="plate-curve-"))
    out = ["--out", str(scratch / "run"), "--force", "--quiet", "--no-plots"]
    tablet_shape = CASES["tablet"][1]
    series = {
        "modes kept (tablet panel)": [(n, ["run", "--model", str(TABLET), *tablet_shape, "--focus-time", "25ms",
                                           "--modes", str(n), "--margin", "none", *out])
                                      for n in ((64, 128, 254) if quick else (64, 96, 128, 192, 254))],  # below 64 the
        # convex planner refuses: holding the other ~200 modes still at T_F asks more than its columns can meet
        "grid points (panel-rounded)": [(nx * ny, ["run", "--scene", "panel-rounded", "--points", f"{nx}x{ny}", *BUMP,
                                                   "--focus-time", "25ms", "--tau-target", "0.9", *out])
                                        for nx, ny in ((31, 18), (61, 36), (121, 71), (241, 141))],
        "shot length (panel-rounded)": [(tf, ["run", "--scene", "panel-rounded", *BUMP, "--focus-time", f"{tf}ms",
                                              "--tau-target", "0.9", *out]) for tf in (10, 25, 50, 100)],
    }
    curves = {}
    for name, points in series.items():
        rows = []
        for x, command in points:
            print(f"{name} = {x}: modalctl {' '.join(command)}", flush=True)
            rows.append({"x": x, **summary(measured(command, memory=True))})  # its memory charted too
        curves[name] = {"rows": rows, "slopes": slopes(rows)}
    shutil.rmtree(scratch, ignore_errors=True)
    return curves


def slopes(rows: list[dict]) -> dict:
    """Each stage's (and the peak memory's) log-log slope against x, over the rows that ran."""
    ok = [r for r in rows if r["exit"] == 0]
    found = {}
    for stage in (*STAGES, "peak memory"):
        pairs = [(r["x"], r["peak_mb"] if stage == "peak memory" else r["stages_s"].get(stage)) for r in ok]
        pairs = [(x, y) for x, y in pairs if y is not None and y > 1e-4]
        if len(pairs) >= 3:
            x, y = np.log(np.array(pairs, float)).T
            found[stage] = float(np.polyfit(x, y, 1)[0])
    return found


def report(data: dict, json_path: Path) -> None:
    """results/plate_speed.md and .png from the measured data."""
    lines = ["# Plate speed: each stage of a shot's command", "",
             "`python benchmarks/plate_speed.py`; wall time median of "
             f"{REPEATS} fresh processes for open loop (1 for closed loops, the tablet and the baseline), nothing "
             "watching them; peak memory (proportional set size of the process and the children it forks) from one "
             "more run, sampled every 20 ms (the sampling slowed the panel's open loop by 0.5 s: it is not in the "
             "times); stages from each run's metrics.json. "
             f"Baseline: commit {data.get('commands', {}).get('baseline') or '-'} in the same run.", ""]
    commands = data.get("commands")
    if commands:
        t = commands["tablet_model"]
        pace = commands.get("speed")
        if pace:
            lines += ["The machine's pace (`common.speed_probe`: an interpreter loop of 10^7 additions, five 1000 x "
                      f"1000 products) before the commands: {pace['before']['python_loop_s']:.2f} s and "
                      f"{pace['before']['matmul_s']:.2f} s; after: {pace['after']['python_loop_s']:.2f} s and "
                      f"{pace['after']['matmul_s']:.2f} s. The probe misses slowdowns that come and go within minutes "
                      "(0.45-1.05 s within an hour of 2026-11-28, commands 1.5-2.5 times slower at its fast end): "
                      "compare each command with the baseline in the same run.", ""]
        lines += [f"Tablet panel `modalctl model fe --band 20kHz` (from the cache's mesh-free start, a fresh solve): "
                  f"{t['wall_s']:.1f} s, {t['peak_mb']:.0f} MB peak, exit {t['exit']}.", "",
                  "| case | loop | wall s (baseline) | peak MB (baseline) | folder MB | plan s | play s | scan s | write s "
                  "| loop update us, median (99%) | tau | margin | modes kept / model |", "|" + "---|" * 13]
        for key, row in commands["cases"].items():
            case, loop = key.split("/")
            now, then = row["now"], row.get("baseline")
            if now["exit"] != 0:
                lines.append(f"| {case} | {loop} | exit {now['exit']}: {now['error']} |" + " |" * 10)
                continue
            s = now["stages_s"]
            base = "" if not then else (f" ({then['wall_s']:.1f})" if then["exit"] == 0 else f" (exit {then['exit']})")
            base_mb = "" if not then or then["exit"] != 0 else f" ({then['peak_mb']:.0f})"
            lines.append(
                f"| {case} | {loop} | {now['wall_s']:.1f}{base} | {now['peak_mb']:.0f}{base_mb} | "
                f"{now['folder_mb'] or 0:.1f} | {_f(s.get('plan'))} | {_f(s.get('play'))} | {_f(s.get('scan'))} | "
                f"{_f(s.get('write'))} | {_update(now)} | {_f(now['tau'], '{:.3f}')} | "
                f"{_f(now['margin_ratio'], '{:.3f}')} | {now['modes_kept']} / {now['model_modes']} |")
        lines += ["", "## The issue's targets", "", "| target | measured | at most | met |", "|---|---|---|---|"]
        for what, key, field, most in TARGETS:
            value = _target_value(commands["cases"].get(key, {}).get("now"), field)
            lines.append(f"| {what} | {_f(value, '{:.3g}')} | {most:g} | "
                         f"{'**no** (did not succeed)' if value is None else 'yes' if value <= most else '**no**'} |")
        lines.append(f"| tablet `model fe --band 20kHz` (s / MB) | {t['wall_s']:.1f} / {t['peak_mb']:.0f} | 30 / 2000 | "
                     f"{'yes' if t['exit'] == 0 and t['wall_s'] <= 30 and t['peak_mb'] <= 2000 else '**no**'} |")
    curves = data.get("curves")
    if curves:
        lines += ["", "## The cost curve: fitted log-log slopes (1: linear)", "",
                  "| grows | " + " | ".join((*STAGES, "peak memory")) + " |", "|" + "---|" * (len(STAGES) + 2)]
        for name, curve in curves.items():
            lines.append(f"| {name} | " + " | ".join(_f(curve["slopes"].get(s), "{:.2f}")
                                                   for s in (*STAGES, "peak memory")) + " |")
    write_markdown("plate_speed", lines, json_path)
    _chart(data)


def _target_value(row: dict | None, field: str) -> float | None:
    """A run's ``field`` (a stage's seconds, or a summary's own key); None when it did not succeed."""
    if not row or row["exit"] != 0:
        return None
    return row["stages_s"].get(field) if field in STAGES else row.get(field)


def _f(value, form: str = "{:.2f}") -> str:
    return "-" if value is None else form.format(value)


def _chart(data: dict) -> None:
    from matplotlib.figure import Figure

    curves = data.get("curves") or {}
    commands = (data.get("commands") or {}).get("cases", {})
    fig = Figure(figsize=(15, 9))
    axes = fig.subplots(2, 2).ravel()
    for ax, (name, curve) in zip(axes, curves.items()):
        ok = [r for r in curve["rows"] if r["exit"] == 0]
        x = np.array([r["x"] for r in ok], float)
        for i, stage in enumerate(STAGES):
            y = np.array([r["stages_s"].get(stage) or np.nan for r in ok], float)
            if np.all(~np.isfinite(y) | (y <= 0)):
                continue
            slope = curve["slopes"].get(stage)
            ax.loglog(x, y, "o-", color=f"C{i}", label=f"{stage} (slope {slope:.2f})" if slope is not None else stage)
        memory = ax.twinx()
        memory.loglog(x, [r["peak_mb"] for r in ok], "k--", label="peak memory")
        memory.set_ylabel("peak memory (MB, dashed)")
        ax.set_xlabel(name)
        ax.set_ylabel("stage time (s)")
        ax.legend(fontsize=7, loc="upper left")
        ax.set_title(f"cost against {name}")
    ax = axes[3]
    labels, now, then, missing = [], [], [], []
    for key, row in commands.items():
        if row["now"]["exit"] == 0:
            labels.append(key.replace("/", "\n"))
            now.append(row["now"]["wall_s"])
            b = row.get("baseline")
            then.append(b["wall_s"] if b and b["exit"] == 0 else np.nan)
            missing.append(None if b and b["exit"] == 0 else f"exit {b['exit']}" if b else "not run")
    pos = np.arange(len(labels))
    ax.bar(pos - 0.2, then, 0.4, color="0.6", label="baseline (before issues 35-36)")
    ax.bar(pos + 0.2, now, 0.4, color="C0", label="now")
    ax.set_yscale("log")
    ax.set_ylim(1, None)  # bars rise from 1 s: the open loops' 4 s show, not a sliver above the axis
    for x, said in zip(pos, missing):  # a baseline that failed or was not run is said, not left a gap
        if said:
            ax.text(x - 0.2, 0.02, said, rotation=90, fontsize=7, ha="center", va="bottom", color="0.3",
                    transform=ax.get_xaxis_transform())
    ax.set_xticks(pos, labels, fontsize=7, rotation=60, ha="right")
    ax.set_ylabel("command wall time (s)")
    ax.set_title("each command, now and before")
    ax.legend(fontsize=8)
    fig.tight_layout()
    RESULTS.mkdir(exist_ok=True)
    fig.savefig(RESULTS / "plate_speed.png", dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", choices=("commands", "curve"), action="append")
    parser.add_argument("--no-baseline", action="store_true")
    parser.add_argument("--quick", action="store_true", help="fewer repeats and points (a check of the script)")
    parser.add_argument("--quick-curve", action="store_true", help="fewer points on the cost curve only")
    parser.add_argument("--report-only", action="store_true")
    args = parser.parse_args()
    if args.report_only:
        report(*read_json("plate_speed"))
        return
    parts = args.part or ["commands", "curve"]
    data = read_json("plate_speed")[0] if (RESULTS / "plate_speed.json").exists() else {}  # a part run alone
    data.pop("machine", None)  # keeps the other's last numbers
    if "commands" in parts:
        data["commands"] = run_commands(not args.no_baseline, args.quick)
        report(data, write_json("plate_speed", data))  # kept before the curve starts
    if "curve" in parts:
        data["curves"] = run_curve(args.quick or args.quick_curve)
        report(data, write_json("plate_speed", data))


if __name__ == "__main__":
    main()
