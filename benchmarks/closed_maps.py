"""Where each method fails: tau and margin against drift and finger damping.

    python benchmarks/closed_maps.py                 # writes benchmarks/results/closed_maps.{json,md,png}
    python benchmarks/closed_maps.py --part plates   # one part: beam, plates (the others kept from the JSON)

The thesis's sinc 18 mm at 24 mm (T_F 25 ms, automatic modes, kappa = 1), damping +20% and
40 dB of sensor noise throughout; every resonance drifts by 0-3% and a finger (a viscous damper
at the focus point, which couples the modes) presses with 0-1 N s/m. The methods of
:mod:`modalctl.experiments.sweep` (open loop, closed loop, with tracking, learned), on the thesis's
plan and again under the thesis's 0.5 margin (the convex planner). The same code as
``modalctl sweep --vary drift=0,1%,2%,3% --vary finger=0,0.1,0.3,1 --damping-error 20%``.

The plates: finger.py's cases on plate-glass, plate-glass-clamped and panel-rounded (their models
grown as ``run`` grows them), planned as ``run`` plans by default (convex, under the 0.5 margin),
open loop against the default closed loop and against it after a learning shot (tracked: ``run
--learn tracker``, a closed-loop first shot whose pole trackers update the model; learned: ``run
--learn``, an open-loop first shot whose record does; the reported shot planned on it without the
closed loop's drift band), drift 0-3% and a finger of 0-1 N s/m on the target's peak, 40 dB, the
models' damping exact.
"""

from __future__ import annotations

import argparse
import itertools
import json
import time

from common import RESULTS, write_json, write_markdown
from finger import CASES

from modalctl.experiments.executor import LocalExecutor
from modalctl.experiments.sweep import METHODS, Case, run_case
from modalctl.options import THESIS_MARGIN
from modalctl.report import plot_sweep_maps, sweep_table

DRIFT = (0.0, 0.01, 0.02, 0.03)
FINGER = (0.0, 0.1, 0.3, 1.0)
PLANS = {"": {}, "_margin": {"planner": "convex", "margin": THESIS_MARGIN}}  # the thesis's plan; under the margin
PLATE_CASES = [label for label in CASES if not label.startswith("al-cc")]  # finger.py's plates and panel
PLATE_METHODS = ("open", "closed", "tracked", "learned")
PLATE_FINGER = (0.0, 0.3, 1.0)
HEAD = ["# Where each method fails: drift and a finger", "",
        "Command: `python benchmarks/closed_maps.py`. tau (margin ratio) measured as `modalctl run` measures (the "
        "simulated vibrometer over the whole shot, its noise included); SNR 40 dB throughout."]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", choices=("all", "beam", "plates"), default="all")
    part = parser.parse_args().part
    old = RESULTS / "closed_maps.json"
    data = json.loads(old.read_text()) if part != "all" and old.exists() else {}
    data.pop("markdown", None)
    if part in ("all", "beam"):
        data.update(beam())
    if part in ("all", "plates"):
        data["plates"] = plates()
    md = HEAD + [line for key in ("thesis_plan", "_margin") for line in data.get(key, {}).get("markdown", [])]
    md += [line for case in data.get("plates", {}).values() for line in case["markdown"]]
    path = write_json("closed_maps", data)
    write_markdown("closed_maps", md + [""], path)


def beam() -> dict:
    """The thesis's sinc on thesis-al-cc, damping +20%: every method, on the thesis's plan and under the margin."""
    data = {}
    for suffix, plan in PLANS.items():
        cases = [Case(method=m, drift=d, finger=f, damping_error=0.2, **plan)
                 for m, d, f in itertools.product(METHODS, DRIFT, FINGER)]
        start = time.perf_counter()
        rows = LocalExecutor().map(run_case, cases, progress=True)
        wall = time.perf_counter() - start
        plot_sweep_maps(rows, ["drift", "finger"], list(METHODS), RESULTS / f"closed_maps{suffix}.png")
        data[suffix or "thesis_plan"] = {"rows": rows, "wall_seconds": wall, "finger_added_damping_max": _added(rows)}
        title = ("The thesis's plan (envelopes at kappa = 1, no margin)" if not plan else
                 f"Under the {THESIS_MARGIN:g} margin (convex planner; a closed loop plans with headroom)")
        data[suffix or "thesis_plan"]["markdown"] = _section(
            f"thesis-al-cc, sinc 18 mm at 24 mm, T_F 25 ms, damping +20%: {title}", f"closed_maps{suffix}.png",
            rows, wall)
    return data


def plates() -> dict:
    """finger.py's plate and panel cases, as ``run`` plans them (convex, 0.5 margin), open and the default
    closed loop."""
    data = {}
    for label in PLATE_CASES:
        scene, shape, params = CASES[label]
        cases = [Case(scene=scene, shape=shape, params=tuple(params.items()), points=None, method=m, drift=d,
                      finger=f, planner="convex", margin=THESIS_MARGIN)
                 for m, d, f in itertools.product(PLATE_METHODS, DRIFT, PLATE_FINGER)]
        start = time.perf_counter()
        rows = LocalExecutor().map(run_case, cases, progress=True)
        wall = time.perf_counter() - start
        picture = f"closed_maps_{scene}.png"
        plot_sweep_maps(rows, ["drift", "finger"], list(PLATE_METHODS), RESULTS / picture)
        title = f"{scene}, {label}, T_F 25 ms: under the {THESIS_MARGIN:g} margin, the default closed loop"
        data[label] = {"rows": rows, "wall_seconds": wall, "finger_added_damping_max": _added(rows),
                       "markdown": _section(title, picture, rows, wall)}
    return data


def _section(title: str, picture: str, rows: list, wall: float) -> list[str]:
    """A part's markdown: its title, picture, the finger's strength and the table of tau (margin)."""
    added = _added(rows)
    return ["", f"## {title}", "", f"Picture: `{picture}`. Finger on the target's peak: the largest added damping "
            "of a kept mode, relative to its own, is " + ", ".join(f"{f:g} N s/m: x{1 + a:.1f}"
                                                                      for f, a in sorted(added.items())) + ".", "",
            sweep_table(rows, ["drift", "finger"]), f"{len(rows)} cases in {wall:.0f} s on the local process pool."]


def _added(rows: list) -> dict:
    """The largest damping a finger adds to a kept mode, relative to its own, per finger (N s/m)."""
    return {r["finger"]: r["finger_added_damping_max"] for r in rows if r["finger_added_damping_max"] is not None}


if __name__ == "__main__":
    main()
