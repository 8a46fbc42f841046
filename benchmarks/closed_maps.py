"""Where each method fails: tau and margin against drift and finger damping.

    python benchmarks/closed_maps.py   # writes benchmarks/results/closed_maps.{json,md,png}

The thesis's sinc 18 mm at 24 mm (T_F 25 ms, automatic modes, kappa = 1), damping +20% and
40 dB of sensor noise throughout; every resonance drifts by 0-3% and a finger (a viscous damper
at the focus point, which couples the modes) presses with 0-1 N s/m. The methods of
:mod:`modalctl.experiments.sweep` (open loop, closed loop, with tracking, learned), on the thesis's
plan and again under the thesis's 0.5 margin (the convex planner). The same code as
``modalctl sweep --vary drift=0,1%,2%,3% --vary finger=0,0.1,0.3,1 --damping-error 20%``.
"""

from __future__ import annotations

import itertools
import time

from common import RESULTS, write_json, write_markdown

from modalctl.experiments.executor import LocalExecutor
from modalctl.experiments.sweep import METHODS, Case, run_case
from modalctl.options import THESIS_MARGIN
from modalctl.report import plot_sweep_maps, sweep_table

DRIFT = (0.0, 0.01, 0.02, 0.03)
FINGER = (0.0, 0.1, 0.3, 1.0)
PLANS = {"": {}, "_margin": {"planner": "convex", "margin": THESIS_MARGIN}}  # the thesis's plan; under the margin


def main() -> None:
    data, md = {}, ["# Where each method fails: drift and a finger", "",
                    "Command: `python benchmarks/closed_maps.py`. sinc 18 mm at 24 mm, T_F 25 ms, damping +20%, "
                    "SNR 40 dB; tau (margin ratio) measured as `modalctl run` measures (the simulated vibrometer "
                    "over the whole shot, its noise included)."]
    for suffix, plan in PLANS.items():
        cases = [Case(method=m, drift=d, finger=f, damping_error=0.2, **plan)
                 for m, d, f in itertools.product(METHODS, DRIFT, FINGER)]
        start = time.perf_counter()
        rows = LocalExecutor().map(run_case, cases, progress=True)
        wall = time.perf_counter() - start
        plot_sweep_maps(rows, ["drift", "finger"], list(METHODS), RESULTS / f"closed_maps{suffix}.png")
        added = {r["finger"]: r["finger_added_damping_max"] for r in rows}
        data[suffix or "thesis_plan"] = {"rows": rows, "wall_seconds": wall, "finger_added_damping_max": added}
        title = ("The thesis's plan (envelopes at kappa = 1, no margin)" if not plan else
                 f"Under the {THESIS_MARGIN:g} margin (convex planner; a closed loop plans with headroom)")
        md += ["", f"## {title}", "", f"Picture: `closed_maps{suffix}.png`. Finger at the focus point: the largest "
               "added damping of a kept mode, relative to its own, is "
               + ", ".join(f"{f:g} N s/m: x{1 + a:.1f}" for f, a in sorted(added.items())) + ".", "",
               sweep_table(rows, ["drift", "finger"]), f"{len(rows)} cases in {wall:.0f} s on the local process pool."]
    path = write_json("closed_maps", data)
    write_markdown("closed_maps", md + [""], path)


if __name__ == "__main__":
    main()
