"""A loop update's cost, in the shot and on its own: the loops' per-period arithmetic compiled (numba,
``modalctl.loops.kernels``) against the numpy it replaced, in the same run.

    python benchmarks/loop_update.py                # about 6 minutes
    python benchmarks/loop_update.py --report-only  # redraw from results/loop_update.json

writes benchmarks/results/loop_update.{json,md,png}.

Each case is ``modalctl run`` as plate_speed.py types it, closed loop with 1% drift, 40 dB and a finger of
1 N s/m resting on the scene's centre, under the touch controller (``--controller touch``, the issue's
target: 50 us, a period at 20 kHz) and the default (``touch+cluster``). In a fresh process each:

- **in the shot**: the runtime's own measure of each period's update (reading to command, the read and the
  write outside), median and 99th percentile over the shot's periods. The hardware-in-the-loop board
  simulates the plate between two updates (about 0.5 ms of numpy on a panel), which leaves the update's
  data out of the processor's caches each period;
- **replayed**: the same runtime, controller and supervisor, fed the shot's recorded readings again
  (the board's read returns them, its writes go nowhere; the controller reset first), ``REPEATS`` times in
  the process: the smallest median over the repeats (and that repeat's 99th percentile). That is the update
  as a board whose read is a transfer, not a simulation, would run it.

Beside each, the same on the commit before the kernels (``NUMPY``: its modalctl from a git worktree under
benchmarks/.cache, run by this environment's python). The machine is shared: compare the two in the same
run, not with another run's numbers.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from common import main_or_report, save_figure, speed_probe, write_json, write_markdown

ROOT = Path(__file__).resolve().parents[1]
NUMPY = "7b8cf38"  # main before the loops' kernels
REPEATS = 7
TIMEOUT_S = 300
BUMP = ["--shape", "bump", "--param", "width=30mm", "--param", "center=-20mm,5mm"]
CASES = {  # as plate_speed.py's, the finger resting on the shape's centre
    "thesis-al-cc": ["--scene", "thesis-al-cc", "--shape", "sinc", "--param", "width=18mm", "--param", "center=24mm"],
    "plate-glass": ["--scene", "plate-glass", *BUMP],
    "panel-rounded": ["--scene", "panel-rounded", *BUMP],
}
CONTROLLERS = {"touch": ["--controller", "touch"], "default": []}
SHOT = ["--focus-time", "25ms", "--loop", "closed", "--drift", "1%", "--snr", "40", "--finger", "1Ns/m"]
TARGET_US = 50.0


def replay(arguments: list[str], repeats: int) -> dict:
    """Run ``modalctl run arguments`` in this process, recording the readings the runtime reads; then play
    them through the same runtime ``repeats`` times. The shot's and the replays' per-period costs (us)."""
    from modalctl.cli import main
    from modalctl.loops import runtime as rt

    seen: dict = {"reads": []}
    update = rt.Runtime.update

    def recording(self):
        seen["runtime"], board = self, self.board
        read = board.read

        def kept():
            reading = read()
            seen["reads"].append(None if reading is None else np.array(reading))
            return reading

        board.read = kept
        try:
            return update(self)
        finally:
            del board.read

    rt.Runtime.update = recording
    try:
        main(["run", *arguments])
    except SystemExit as exc:
        if exc.code:
            raise
    finally:
        rt.Runtime.update = update
    if "runtime" not in seen:
        print("loop_update.py: error: the shot ran no loop on the host (open loop, or loops on the board): give "
              "--loop closed", file=sys.stderr)
        sys.exit(2)
    runtime, reads = seen["runtime"], seen["reads"]
    shot = np.array(runtime._costs) * 1e6
    board = runtime.board
    board.start = board.play_out = lambda *a: None
    board.write = board.ramp_down = lambda *a: None
    runtime.recorder = None
    medians, p99s = [], []
    for _ in range(repeats):
        readings = iter(reads)
        board.read = lambda: next(readings)
        runtime._costs, runtime.state = [], rt.State.INACTIVE
        runtime.activate()
        for _ in reads:
            if runtime.update() != rt.State.ACTIVE:
                break
        costs = np.array(runtime._costs) * 1e6
        medians.append(float(np.median(costs)))
        p99s.append(float(np.percentile(costs, 99)))
    best = int(np.argmin(medians))
    return {"shot_us": float(np.median(shot)), "shot_p99_us": float(np.percentile(shot, 99)),
            "replay_us": medians[best], "replay_p99_us": p99s[best], "replay_medians_us": medians,
            "periods": len(reads)}


def numpy_tree() -> Path | None:
    """A git worktree of :data:`NUMPY` under benchmarks/.cache (made once); None when it cannot be made."""
    where = ROOT / "benchmarks" / ".cache" / f"loop-{NUMPY}"
    if not where.exists():
        made = subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(where), NUMPY],
                              capture_output=True, text=True)
        if made.returncode:
            print(f"no numpy commit: {made.stderr.strip()}", file=sys.stderr)
            return None
    return where


def measured(case: str, controller: str, tree: Path | None) -> dict | None:
    """One case in a fresh process: this checkout's modalctl, or ``tree``'s."""
    env = dict(os.environ, PYTHONPATH=str(tree) if tree else "")
    with tempfile.TemporaryDirectory() as out:
        arguments = [*CASES[case], *SHOT, *CONTROLLERS[controller], "--out", out, "--quiet", "--no-plots"]
        done = subprocess.run([sys.executable, __file__, "--one", json.dumps(arguments)], capture_output=True,
                              text=True, env=env, cwd=out if tree else None, timeout=TIMEOUT_S)
        if done.returncode:
            print(f"{case}/{controller} ({'numpy' if tree else 'kernels'}) failed:\n{done.stderr[-2000:]}",
                  file=sys.stderr)
            return None
        row = json.loads(done.stdout.strip().splitlines()[-1])
        metrics = json.loads((Path(out) / "metrics.json").read_text())
        return {**row, "tau": metrics["tau"], "margin": metrics["margin_ratio"]}


def main() -> None:
    tree = numpy_tree()
    before = speed_probe()
    rows = {}
    for case in CASES:
        for controller in CONTROLLERS:
            key = f"{case}/{controller}"
            rows[key] = {"kernels": measured(case, controller, None),
                         "numpy": measured(case, controller, tree) if tree else None}
            print(key, json.dumps(rows[key]), file=sys.stderr)
    data = {"rows": rows, "numpy_commit": NUMPY if tree else None, "repeats": REPEATS,
            "speed": {"before": before, "after": speed_probe()}}
    report(data, write_json("loop_update", data))


def _pace(probe: dict) -> str:
    return f"{probe['python_loop_s']:.2f} s and {probe['matmul_s']:.2f} s"


def _cell(row: dict | None, field: str) -> str:
    return "-" if not row else f"{row[field]:.0f} ({row[field.replace('_us', '_p99_us')]:.0f})"


def report(data: dict, path: Path) -> None:
    rows = data["rows"]
    lines = ["# A loop update: in the shot and on its own", "",
             "`python benchmarks/loop_update.py`: closed loop, 1% drift, 40 dB, 1 N s/m resting; microseconds a "
             "period from reading to command, median (99th percentile). In the shot: the runtime's own measure, "
             "the board simulating the plate between updates. Replayed: the shot's readings through the same "
             f"runtime again, the smallest median of {data['repeats']} (what a board whose read is a transfer "
             f"would see). numpy: commit {data.get('numpy_commit') or '-'} (before the kernels) in the same run. "
             f"Target: {TARGET_US:.0f} us (a period at 20 kHz), panel-rounded under the touch controller.", "",
             f"The machine's pace (`common.speed_probe`: an interpreter loop, five 1000 x 1000 products) before: "
             f"{_pace(data['speed']['before'])}; after: {_pace(data['speed']['after'])}.", "",
             "| case | controller | in the shot, kernels | in the shot, numpy | replayed, kernels | replayed, numpy "
             "| ratio replayed | tau (kernels / numpy) | margin |",
             "|---|---|---|---|---|---|---|---|---|"]
    for key, row in rows.items():
        case, controller = key.split("/")
        new, old = row["kernels"], row["numpy"]
        ratio = "-" if not (new and old) else f"{old['replay_us'] / new['replay_us']:.2f}"
        tau = "-" if not new else f"{new['tau']:.4f}" + ("" if not old else f" / {old['tau']:.4f}")
        margin = "-" if not new else f"{new['margin']:.3f}" + ("" if not old else f" / {old['margin']:.3f}")
        lines.append(f"| {case} | {controller} | {_cell(new, 'shot_us')} | {_cell(old, 'shot_us')} | "
                     f"{_cell(new, 'replay_us')} | {_cell(old, 'replay_us')} | {ratio} | {tau} | {margin} |")
    write_markdown("loop_update", lines, path)
    _draw(rows)


def _draw(rows: dict) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9, 4.2))
    ax = fig.subplots()
    keys = list(rows)
    pos = np.arange(len(keys))
    bars = [("numpy, in the shot", "numpy", "shot_us", "0.75"), ("numpy, replayed", "numpy", "replay_us", "0.45"),
            ("kernels, in the shot", "kernels", "shot_us", "tab:orange"),
            ("kernels, replayed", "kernels", "replay_us", "tab:blue")]
    for i, (label, which, field, colour) in enumerate(bars):
        values = [np.nan if not rows[k][which] else rows[k][which][field] for k in keys]
        ax.bar(pos + (i - 1.5) * 0.2, values, 0.2, color=colour, label=label)
    ax.axhline(TARGET_US, color="k", ls="--", lw=1, label=f"{TARGET_US:.0f} us: a period at 20 kHz")
    ax.set_xticks(pos, [k.replace("/", "\n") for k in keys], fontsize=8)
    ax.set_ylabel("loop update, median (us)")
    ax.set_title("A loop update, numpy against compiled kernels (closed loop, 1% drift, 40 dB, 1 N s/m)")
    ax.legend(fontsize=8)
    save_figure(fig, "loop_update")


def _one(text: str) -> list[str]:
    """The internal ``--one`` runner's argument: ``modalctl run``'s arguments as a JSON list of strings
    (what :func:`measured` passes); anything else exits 2 with what was wrong."""
    try:
        arguments = json.loads(text)
    except ValueError:
        arguments = None
    if not (isinstance(arguments, list) and arguments and all(isinstance(a, str) for a in arguments)):
        print(f"loop_update.py: error: --one takes modalctl run's arguments as a JSON list of strings, got "
              f"{text[:200]!r}", file=sys.stderr)
        sys.exit(2)
    return arguments


if __name__ == "__main__":
    if len(sys.argv) >= 2 and sys.argv[1] == "--one":
        print(json.dumps(replay(_one(" ".join(sys.argv[2:])), REPEATS)))
    else:
        main_or_report("loop_update", main, report)
