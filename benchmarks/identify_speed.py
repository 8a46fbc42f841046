"""The identification survey as a user types it: ``modalctl identify --scene NAME`` with its defaults.

    python benchmarks/identify_speed.py                # about 7 min (the baseline's plate runs to its timeout)
    python benchmarks/identify_speed.py --no-baseline

writes benchmarks/results/identify_speed.{json,md}. Each command runs in a fresh process
(:func:`plate_speed.measured`: wall time, the peak memory of the process and its children), on
thesis-al-cc and plate-glass (21 modes to 12 kHz, 7,171 points; every actuator over a fifth of them,
the primary over all, 100 Hz - 100 kHz): issue 39's "did not finish in
300 s". Beside each, the same command on the commit before issues 35-39 (``plate_speed.BASELINE``, in
its own virtual environment) in the same run, and what was identified: the scene's modes found within
1% (the scene is the truth the simulator plays), the largest frequency error among them, the modes
returned that are none of the scene's.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
from common import write_json, write_markdown
from plate_speed import PYTHON, baseline_python, measured

from modalctl.model.scenes import load_scene

SCENES = ("thesis-al-cc", "plate-glass")
TIMEOUT_S = 240  # a survey past it is a result (the baseline's plate: past 300 s)


def identified(path: Path, scene: str) -> dict:
    """What the model file at ``path`` holds against the scene's modes: found within 1%, the largest
    relative frequency error among them, the modes that are none of the scene's."""
    truth = load_scene(scene).frequencies
    found = np.load(path)["frequencies"]
    error = np.abs(found[:, None] / truth[None, :] - 1)
    nearest = error.min(axis=0)
    return {"modes": int(found.size), "found": int(np.sum(nearest <= 0.01)), "of": int(truth.size),
            "worst_error": float(nearest[nearest <= 0.01].max()) if np.any(nearest <= 0.01) else None,
            "spurious": int(np.sum(error.min(axis=1) > 0.01))}


def survey(scene: str, python: str) -> dict:
    """``identify --scene scene`` in a fresh process with ``python``'s modalctl, and what it found."""
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "model.npz"
        row = measured(["identify", "--scene", scene, "--no-plots", "--out", str(out)], python, timeout=TIMEOUT_S)
        row.pop("metrics", None)
        if row["exit"] == 0:
            row.update(identified(out, scene))
    return row


def report(rows: dict) -> None:
    lines = ["# The identification survey's cost", "",
             "`python benchmarks/identify_speed.py`: `modalctl identify --scene NAME --no-plots` with every other "
             "option at its default, one fresh process each; peak memory of the process and its children. "
             f"Baseline: commit {rows['baseline_commit']} (before issues 35-39), its own virtual environment, "
             "in the same run. Found: the scene's modes matched within 1%.", "",
             "| scene | version | wall s | peak MB | modes found | worst error | spurious | ratio to baseline (wall) |",
             "|---|---|---|---|---|---|---|---|"]
    for scene in SCENES:
        now, before = rows["now"][scene], rows.get("baseline", {}).get(scene)
        for name, row in (("now", now), ("baseline", before)):
            if row is None:
                continue
            if row["exit"] != 0:
                lines.append(f"| {scene} | {name} | {row['wall_s']:.1f} | {row['peak_mb']:.0f} | exit {row['exit']}: "
                             f"{row.get('error', '?')} | | | |")
                continue
            ratio = ""
            if name == "now" and before is not None:
                ratio = f"{row['wall_s'] / before['wall_s']:.2f}" + ("" if before["exit"] == 0 else " (or less)")
            worst = "-" if row["worst_error"] is None else f"{100 * row['worst_error']:.3f}%"
            lines.append(f"| {scene} | {name} | {row['wall_s']:.1f} | {row['peak_mb']:.0f} | {row['found']} of "
                         f"{row['of']} ({row['modes']} returned) | {worst} | {row['spurious']} | {ratio} |")
    write_markdown("identify_speed", lines + [""], write_json("identify_speed", rows))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--no-baseline", action="store_true")
    args = parser.parse_args()
    from plate_speed import BASELINE

    rows = {"baseline_commit": BASELINE, "now": {}}
    for scene in SCENES:
        print(f"identify --scene {scene}", flush=True)
        rows["now"][scene] = survey(scene, PYTHON)
    old = None if args.no_baseline else baseline_python()
    if old is not None:
        rows["baseline"] = {}
        for scene in SCENES:
            print(f"identify --scene {scene} (baseline {BASELINE})", flush=True)
            rows["baseline"][scene] = survey(scene, old)
    report(rows)


if __name__ == "__main__":
    main()
