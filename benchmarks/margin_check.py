"""How fast the convex planner's check finds where a drive's field passes the margin, by the shape of its
cover of boxes, against the whole grid's product.

    python benchmarks/margin_check.py                # writes benchmarks/results/margin_check.{json,md,png}
    python benchmarks/margin_check.py --report-only  # redraws the table and the figure from the JSON

Each round of the margin program checks every plant (the model and its four drifted copies) on every
off-target grid point and DAC sample: :meth:`modalctl.plan.convex_cover.Cover.top`, exact wherever the field
exceeds the level the rows lie above (``aim`` of the margin), a proven bound below it. The drives here are
what a closed loop plans (margin 0.45 over +-2% of drift, 1 MS/s, T_F 25 ms): the last round's of
panel-rounded's 30 mm bump at (-20, 5) mm (the model grown to 53 modes, as ``modalctl run`` grows it) and of
the tablet panel's 20 mm bump (``common.tablet_arguments``, tau 0.95, 255 modes, 31,548 off-target points).

For each shape of the cover (at most ``leaf`` points in its smallest boxes, ``2^splits`` children a box, the
``components`` of the affine fits' residuals each box's bound keeps apart) the
median time of a search per plant (3 repeats of the five plants), against the peer: NumPy/BLAS's product of
every point's shapes with every sample's modal velocities and its largest value per sample (the whole grid's
field, one plant, in blocks of 1,024 samples). Every search is checked equal to the peer's above the level.
"""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
from common import main_or_report, save_figure, target, write_json, write_markdown
from plate_speed import TABLET, TABLET_COMMAND

from modalctl.api import load_model
from modalctl.model.scenes import load_scene
from modalctl.options import PlanOptions
from modalctl.plan.convex_cover import COMPONENTS, LEAF, SPLITS, Cover
from modalctl.plan.convex_program import Program
from modalctl.plan.decompose import decompose
from modalctl.plan.growth import model_for

NAME = "margin_check"
# (leaf, splits, components); (16, 3, 0) the cover before 2026-11-29, (32, 5, 0) before 2026-11-30
SHAPES = [(16, 3, 0), (32, 5, 0), (32, 5, 6), (64, 5, 0), (64, 5, 4), (64, 5, 6), (64, 5, 8), (96, 5, 6), (128, 6, 8)]
REPEATS = 3
BLOCK = 1024  # the peer's samples at once: the points-by-samples product's memory (the tablet's: 260 MB)
OPTIONS = PlanOptions(margin=0.45, robust_drift=0.02)  # what a closed loop asks of a 0.5 margin
CASES = {  # case: (how its model is made, shape, centre, width, tau target)
    "panel-rounded": ("scene", "bump", "-20mm,5mm", "30mm", 0.98),
    "tablet": ("tablet", "bump", "-20mm,5mm", "20mm", 0.95),
}


def drives(case: str) -> tuple[Program, int, list, float]:
    """The margin program of ``case``, the rounds it took, every plant's modal velocities (K, N) on its drive,
    and the level the check is asked (``aim`` of the margin of the focus peak)."""
    source, shape_name, centre, width, tau_min = CASES[case]
    if source == "tablet":
        if not TABLET.exists():
            TABLET.parent.mkdir(parents=True, exist_ok=True)
            print("solving the tablet panel once:", " ".join(TABLET_COMMAND), flush=True)
            subprocess.run([sys.executable, "-m", "modalctl", *TABLET_COMMAND], check=True)
        model = load_model(TABLET)
    else:
        model = load_scene(case)
    shape = target(model, shape_name, width=width, center=centre)
    options = OPTIONS.but(tau_min=tau_min)
    model, _ = model_for(model, shape, options)
    shape = target(model, shape_name, width=width, center=centre)
    dec = decompose(model, shape, "auto", tau_min=tau_min)
    modes = np.arange(int(np.max(dec.modes_used)) + 1)  # every mode below the highest, as a closed loop keeps
    program = Program(model, modes, dec.coefficients[modes], shape.target_mask, 0.025, options)
    solution = program.solve()
    _, velocities = program.play(solution.x)
    return program, solution.rounds, velocities, options.convex.aim * options.margin * program.peak


def whole_grid(values: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """The peer: the largest |w| over every point at each sample, the field made whole by BLAS (N,)."""
    return np.concatenate([np.abs(values @ velocity[:, i:i + BLOCK]).max(axis=0)
                           for i in range(0, velocity.shape[1], BLOCK)])


def measure(case: str) -> dict:
    program, rounds, velocities, level = drives(case)
    shapes = program.model.shapes[:, program.outside]
    points = program.model.grid.points[program.outside]
    tic = time.perf_counter()
    truth = whole_grid(shapes.T, velocities[0])
    peer = time.perf_counter() - tic
    rows = []
    for leaf, splits, components in SHAPES:
        tic = time.perf_counter()
        cover = Cover(shapes, points, leaf=leaf, splits=splits, components=components)
        built = time.perf_counter() - tic
        seconds = []
        for _ in range(REPEATS):
            for velocity in velocities:
                tic = time.perf_counter()
                cover.top(velocity, level)
                seconds.append(time.perf_counter() - tic)
        top = cover.top(velocities[0], level)
        above = truth > level
        exact = bool(np.allclose(top[above], truth[above], rtol=1e-12, atol=0) and np.all(top[~above] <= level))
        rows.append({"leaf": leaf, "splits": splits, "children": 2 ** splits, "components": components,
                     "build_s": built, "top_s": float(np.median(seconds)), "exact": exact,
                     "default": (leaf, splits, components) == (LEAF, SPLITS, COMPONENTS)})
        print(f"{case}: leaf {leaf}, {2 ** splits} children, {components} components: "
              f"{1e3 * rows[-1]['top_s']:.1f} ms a plant (exact {exact})", flush=True)
    return {"points": int(shapes.shape[1]), "modes": int(shapes.shape[0]), "samples": int(velocities[0].shape[1]),
            "plants": len(velocities), "rounds": rounds,
            "above": int(np.count_nonzero(truth > level)), "peer_s": peer, "shapes": rows}


def main() -> None:
    data = {"cases": {case: measure(case) for case in CASES}, "repeats": REPEATS}
    report(data, write_json(NAME, data))


def report(data: dict, json_path) -> None:
    lines = ["# The margin check's search, by the shape of its cover", "",
             "`python benchmarks/margin_check.py`: the median time of one plant's search "
             "(`Cover.top`, the convex planner's check of a round: exact above aim x the margin) on the last round's "
             "drive of a closed-loop plan (margin 0.45 over +-2%, 1 MS/s), against the whole grid's field made by "
             "NumPy/BLAS (the peer, one plant). exact: the search equals the peer's above the level. components: "
             "the leading components of the residuals of each box's affine fits that its bound keeps apart (0: "
             "the residuals bounded mode by mode).", ""]
    for case, row in data["cases"].items():
        default = next((s for s in row["shapes"] if s["default"]), None)
        before = next((s for s in row["shapes"] if (s["leaf"], s["splits"], s.get("components", 0)) == (32, 5, 0)),
                      None)
        fastest = min(row["shapes"], key=lambda s: s["top_s"])
        if default and before:
            lines += [f"{case}: the default's search {1e3 * default['top_s']:.1f} ms against "
                      f"{1e3 * before['top_s']:.1f} ms for the cover before its components (32 points, 32 children: "
                      f"x{before['top_s'] / default['top_s']:.2f}); the fastest here {fastest['leaf']} / "
                      f"{fastest['children']} / {fastest.get('components', 0)}, {1e3 * fastest['top_s']:.1f} ms.", ""]
        lines += [f"## {case}: {row['modes']} modes, {row['points']:,} off-target points, {row['samples']:,} samples "
                  f"({row['above']:,} above the level)", "",
                  f"The whole grid's field (peer): {row['peer_s']:.2f} s a plant.", "",
                  "| leaf | children | components | search ms (median) | x faster than the peer | build ms | exact |",
                  "|---|---|---|---|---|---|---|"]
        for s in row["shapes"]:
            mark = " (default)" if s["default"] else ""
            lines.append(f"| {s['leaf']}{mark} | {s['children']} | {s.get('components', 0)} | {1e3 * s['top_s']:.1f} | "
                         f"{row['peer_s'] / s['top_s']:.0f} | {1e3 * s['build_s']:.0f} | {s['exact']} |")
        lines.append("")
    write_markdown(NAME, lines, json_path)
    _chart(data)


def _chart(data: dict) -> None:
    import matplotlib.pyplot as plt

    cases = list(data["cases"])
    fig, axes = plt.subplots(1, len(cases), figsize=(5 * len(cases), 3.6))
    for ax, case in zip(np.atleast_1d(axes), cases):
        row = data["cases"][case]
        labels = [f"{s['leaf']} / {s['children']} / {s.get('components', 0)}" for s in row["shapes"]]
        values = [1e3 * s["top_s"] for s in row["shapes"]]
        colours = ["tab:green" if s["default"] else "tab:gray" for s in row["shapes"]]
        ax.bar(labels, values, color=colours)
        ax.axhline(1e3 * row["peer_s"], color="tab:red", linestyle="--", label="whole grid (peer)")
        ax.set_yscale("log")
        ax.set_ylim(bottom=10)  # every bar from one baseline
        ax.set_xlabel("leaf points / children / components (green: default)")
        ax.tick_params(axis="x", labelrotation=45)
        ax.set_ylabel("one plant's search (ms)")
        ax.set_title(f"{case}: {row['modes']} modes, {row['points']:,} points")
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, 0.93), fontsize=8)
    save_figure(fig, NAME)


if __name__ == "__main__":
    main_or_report(NAME, main, report)
