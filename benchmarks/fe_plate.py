"""Finite-element plates: verification, solve time and memory, and focusing on them.

    python benchmarks/fe_plate.py                 # all parts (about 10 min)
    python benchmarks/fe_plate.py --part verify   # one part: verify, speed, tablet, focus

writes benchmarks/results/fe_plate.{json,md,png} (and fe_plate_focus_*.png).

1. ``verify``: the clamped square's first six frequency parameters against Leissa (NASA SP-160,
   Table 4.23), the free square's (nu = 0.3, Table 4.61), the simply supported 100 x 70 mm
   rectangle against the analytic plate (frequencies, MAC); the convergence of the clamped
   square's parameters with the mesh, for the 15-parameter triangle and the peer, Morley's
   triangle (scikit-fem's classic nonconforming plate element), on the same gmsh meshes.
2. ``speed``: the clamped 100 x 70 x 1 mm glass plate, 10 to 60 modes converged to 0.5% (the
   refinement stopping by itself): median wall time of 3 solves and peak memory (a fresh process
   per case, its resident set at the end less a bare import's); Morley's triangle converging the
   same 30 modes to the same tolerance, in the same run (the ratio).
3. ``tablet``: the tablet panel of issue 36 (210 x 150 x 0.7 mm glass, 8 mm corners, clamped, eight
   14 x 10 mm patches in two rows of four at y = +-55 mm), ``modalctl model fe --band 20kHz`` as a
   user runs it (pictures and all) in a fresh process, as it starts and with one BLAS thread: wall
   and CPU time, peak resident memory, dofs, modes; beside the same command measured on the commit
   before the solve was made to scale.
4. ``focus``: on plate-glass-clamped and panel-rounded, the modes a 2-D bump needs against its
   width (tau >= 0.95, the thesis's Fig 4.31 for a plate), and a 40 mm bump focused on the HIL
   open and closed loop with every resonance 1% off the model (grid 51 x 36), the field on the
   plate around T_F drawn.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from common import RESULTS, read_json, save_figure, tablet_arguments, write_json  # noqa: E402

from modalctl.model.fe_plate import MATERIALS, FEPlate, Material, Outline, Support  # noqa: E402
from modalctl.model.structures import Plate  # noqa: E402

LEISSA_CLAMPED = [35.992, 73.413, 73.413, 108.27, 131.64, 132.24]  # Table 4.23
PRECISE_CLAMPED = [35.985, 73.394, 73.394, 108.22, 131.58, 132.20]  # the same, converged further (for the chart)
LEISSA_FREE_NU03 = [13.468, 19.596, 24.270, 34.801, 34.801, 61.093]  # Table 4.61
STEEL = Material(200e9, 7850.0, 0.3)
GLASS = MATERIALS["glass"]
SS_TOLERANCE = 5e-4  # the simply supported rectangle is held to 0.1% against the analytic plate: converged to 0.05%
REPEATS = 3
TAU = 0.95
WIDTHS_MM = (20, 25, 30, 40, 50, 60)
#: The tablet's command on 8c95cc3, the commit before the solve was made to scale (issue 36), measured
#: with /usr/bin/time -v on this 2-core machine shared with other work (load average about 5); run
#: again later by part_tablet beside other work, it was killed out of memory at 13.5 GB after 280 s.
TABLET_BEFORE = {"commit": "8c95cc3", "seconds": 246.8, "cpu_seconds": 170.0, "peak_mb": 16100, "dofs": 48951,
                 "modes": 254}
TABLET_TARGET = {"seconds": 30, "peak_mb": 2048}


def parameters(plate: FEPlate, frequencies, side: float) -> np.ndarray:
    return 2 * np.pi * np.asarray(frequencies) * side**2 * np.sqrt(plate.mass_per_area / plate.rigidity)


def refinement_levels(plate: FEPlate, size: float, levels: int, modes: int) -> list[dict]:
    """Uniform refinement from one gmsh mesh: dofs, seconds and frequencies per level."""
    rows, mesh = [], plate.mesh(size)
    for _ in range(levels):
        start = time.perf_counter()
        freqs, _, _, basis = plate.solve(mesh, modes)
        rows.append({"dofs": int(basis.N), "seconds": time.perf_counter() - start,
                     "frequencies": freqs.tolist()})
        mesh = mesh.refined()
    return rows


def part_verify() -> dict:
    out = {}
    clamped = FEPlate(Outline.rectangle(0.1, 0.1), 1e-3, GLASS, {"rim": Support("clamped")})
    model, conv = clamped.modal_model(6, spacing=2e-3)
    lam = parameters(clamped, model.frequencies, 0.1)
    out["clamped_square"] = {"lambda": lam.tolist(), "leissa": LEISSA_CLAMPED,
                             "error": (lam / LEISSA_CLAMPED - 1).tolist(), "dofs": conv.levels[-1].dofs}
    free = FEPlate(Outline.rectangle(0.1, 0.1), 1e-3, STEEL, {"rim": Support("free")})
    model, conv = free.modal_model(6, spacing=2e-3)
    lam = parameters(free, model.frequencies, 0.1)
    out["free_square"] = {"lambda": lam.tolist(), "leissa": LEISSA_FREE_NU03,
                          "error": (lam / LEISSA_FREE_NU03 - 1).tolist(), "dofs": conv.levels[-1].dofs,
                          "rigid_modes": int(model.rigid_shapes.shape[0])}
    ss = FEPlate(Outline.rectangle(0.1, 0.07), 1e-3, GLASS, {"rim": Support("simply-supported")})
    model, conv = ss.modal_model(21, spacing=1e-3, tolerance=SS_TOLERANCE)
    exact = Plate(0.1, 0.07, 1e-3, GLASS.modulus, GLASS.density, GLASS.poisson).modal_model(21, nx=101, ny=71)
    w = model.grid.mass
    mac = (np.einsum("kn,n,kn->k", model.shapes, w, exact.shapes) ** 2
           / np.einsum("kn,n,kn->k", model.shapes, w, model.shapes) / np.einsum("kn,n,kn->k", exact.shapes, w,
                                                                               exact.shapes))
    out["simply_supported"] = {"max_frequency_error": float(np.max(np.abs(model.frequencies / exact.frequencies - 1))),
                               "min_mac": float(mac.min()), "dofs": conv.levels[-1].dofs}
    out["convergence"] = {name: refinement_levels(
        FEPlate(Outline.rectangle(0.1, 0.1), 1e-3, GLASS, {"rim": Support("clamped")}, element=name),
        0.025, levels, 6) for name, levels in (("15-parameter", 5), ("morley", 6))}
    print("verify:", json.dumps({k: v for k, v in out.items() if k != "convergence"}, default=float)[:600])
    return out


def _peak_kb() -> int:
    """This process's peak resident memory (kB): its own address space's high-water mark. Not
    getrusage's ru_maxrss, which Linux carries over an exec from the process that started it (a
    spawned worker of a parent that once held 2.6 GB reads 2.6 GB before it allocates anything)."""
    try:
        with open("/proc/self/status") as status:
            return next(int(line.split()[1]) for line in status if line.startswith("VmHWM:"))
    except (OSError, StopIteration):
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


def _solve_case(args) -> dict:
    """One solve in a fresh process: its time, and its peak resident memory above the process's
    before it (the libraries loaded), kB."""
    import gmsh  # noqa: F401
    import skfem  # noqa: F401

    modes, element = args
    plate = FEPlate(Outline.rectangle(0.1, 0.07), 1e-3, GLASS, {"rim": Support("clamped")}, element=element)
    before = _peak_kb()
    start = time.perf_counter()
    model, conv = plate.modal_model(modes, spacing=1e-3)
    return {"seconds": time.perf_counter() - start,
            "solve_kb": _peak_kb() - before, "before_kb": before,
            "dofs": conv.levels[-1].dofs, "levels": len(conv.levels), "size_mm": conv.levels[-1].size * 1e3,
            "error": float(conv.frequency_error.max()), "f_max": float(model.frequencies[-1])}


def part_speed() -> dict:
    spawn = multiprocessing.get_context("spawn")
    rows = []
    for modes, element in [(10, "15-parameter"), (20, "15-parameter"), (30, "15-parameter"), (60, "15-parameter"),
                           (30, "morley")]:
        runs = []
        for _ in range(REPEATS):
            with spawn.Pool(1, maxtasksperchild=1) as pool:
                runs.append(pool.map(_solve_case, [(modes, element)])[0])
        row = {"modes": modes, "element": element, **runs[-1],
               "seconds": float(np.median([r["seconds"] for r in runs])),
               "memory_mb": max(r["solve_kb"] for r in runs) / 1024, "process_mb": runs[-1]["before_kb"] / 1024}
        rows.append(row)
        print(f"speed: {modes} modes, {element}: {row['seconds']:.2f} s, {row['memory_mb']:.0f} MB, "
              f"{row['dofs']} dofs, error {row['error']:.3%}")
    ours = next(r for r in rows if r["modes"] == 30 and r["element"] == "15-parameter")
    peer = next(r for r in rows if r["element"] == "morley")
    return {"rows": rows, "ratio_morley_over_ours_30": peer["seconds"] / ours["seconds"]}


def tablet_command(out) -> list[str]:
    """``modalctl model fe`` on the tablet panel (``common.tablet_arguments``), written to ``out``."""
    return ["modalctl", *tablet_arguments(out)]


#: Runs a command and writes its exit status, CPU time and peak resident memory (os.wait4) to the
#: file named first. A small process of its own between the benchmark and the command: Linux
#: carries the starting process's high-water mark over the command's exec into its ru_maxrss.
_MEASURE = ("import json, os, subprocess, sys; child = subprocess.Popen(sys.argv[2:]); _, status, usage = "
            "os.wait4(child.pid, 0); open(sys.argv[1], 'w').write(json.dumps({'exit': "
            "os.waitstatus_to_exitcode(status), 'cpu_seconds': usage.ru_utime + usage.ru_stime, 'peak_kb': "
            "usage.ru_maxrss}))")


def _tablet_run(threads: dict) -> dict:
    """The tablet's command once, in a fresh process with ``threads`` set in its environment."""
    with tempfile.TemporaryDirectory() as folder:
        argv = tablet_command(Path(folder) / "tablet.npz")
        said, usage = Path(folder) / "summary.json", Path(folder) / "usage.json"
        start = time.perf_counter()
        with said.open("w") as out:
            subprocess.run([sys.executable, "-c", _MEASURE, str(usage), str(Path(sys.executable).parent / argv[0]),
                            *argv[1:], "--json"], stdout=out, check=True, env={**os.environ, **threads})
        seconds = time.perf_counter() - start
        usage = json.loads(usage.read_text())
        summary = json.loads(said.read_text().strip().splitlines()[-1]) if usage["exit"] == 0 else {}
    conv = summary.get("convergence", {})
    return {"command": " ".join(argv).replace(str(Path(folder)), "/tmp"), "environment": threads,
            "exit": usage["exit"], "seconds": seconds, "cpu_seconds": usage["cpu_seconds"],
            "peak_mb": usage["peak_kb"] / 1024, "modes": summary.get("modes"),
            "levels_dofs": [lv["dofs"] for lv in conv.get("levels", [])],
            "levels_seconds": [lv["seconds"] for lv in conv.get("levels", [])],
            "error": max(conv.get("frequency_error", [np.nan])), "mac": min(conv.get("shape_mac", [np.nan])),
            "f_max": (summary.get("frequencies_hz") or [np.nan])[-1]}


def part_tablet() -> dict:
    """The tablet's command in a fresh process: wall time, CPU time and peak resident memory of that
    process alone (``os.wait4``), and what it solved (its ``--json`` summary); as it starts, then
    with one BLAS thread (OpenBLAS's threads spin while they wait for a core, and on a machine
    shared with other work they double the CPU time)."""
    rows = []
    for threads in ({}, {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}):
        rows.append(_tablet_run(threads))
        print(f"tablet {threads or 'as it starts'}: {rows[-1]['seconds']:.1f} s ({rows[-1]['cpu_seconds']:.1f} s "
              f"CPU), {rows[-1]['peak_mb']:.0f} MB, {rows[-1]['modes']} modes, dofs {rows[-1]['levels_dofs']}")
    return {"rows": rows, "before": TABLET_BEFORE, "target": TABLET_TARGET,
            "load_average_1_5_15_min": list(os.getloadavg())}


def part_focus() -> dict:
    from modalctl.cli import main
    from modalctl.model.scenes import load_scene
    from modalctl.model.shape import parse_params
    from modalctl.plan.reduction import ReductionError, smallest_set
    from modalctl.plugin.manager import get_shape

    out = {}
    for scene in ("plate-glass-clamped", "panel-rounded"):
        model = load_scene(scene)
        bump = get_shape("bump")
        needed = []
        for width in WIDTHS_MM:
            field = bump.generate(model.grid, **parse_params(bump, {"width": f"{width}mm", "center": "-20mm,5mm"}))
            try:
                needed.append(int(smallest_set(field.values[None], model.shapes, model.grid.mass, tau_min=TAU,
                                               order="magnitude").modes.size))
            except ReductionError:
                needed.append(None)
        runs = {}
        for loop in ("open", "closed"):
            folder = RESULTS / f"fe_plate_runs/{scene}-{loop}"
            shutil.rmtree(folder, ignore_errors=True)
            argv = ["run", "--scene", scene, "--points", "51x36", "--drift", "1%",
                    "--shape", "bump", "--param", "width=40mm", "--param", "center=-20mm,5mm", "--tau-target",
                    str(TAU), "--focus-time", "25ms", "--loop", loop, "--out", str(folder), "--json", "--force"]
            argv += ["--controller", "pi"] if loop == "closed" else []  # the PI loops, as measured (not the default)
            start = time.perf_counter()
            import contextlib
            import io

            said = io.StringIO()
            with contextlib.redirect_stdout(said):
                code = main(argv)
            metrics = json.loads(said.getvalue().strip().splitlines()[-1]) if code == 0 else {"exit": code}
            runs[loop] = {"exit": code, "seconds": time.perf_counter() - start,
                          **{k: metrics.get(k) for k in ("tau", "margin_ratio", "peak_voltage", "modes")}}
            picture = folder / "spacetime.png"
            if picture.exists():
                shutil.copy(picture, RESULTS / f"fe_plate_focus_{scene}_{loop}.png")
            print(f"focus: {scene} {loop}: {runs[loop]}")
        out[scene] = {"widths_mm": list(WIDTHS_MM), "modes_needed": needed, "of": model.n_modes, "runs": runs}
    return out


def report(data: dict, path=None) -> None:
    lines = ["# Finite-element plates: verification, speed, focus", "",
             "Command: `python benchmarks/fe_plate.py` (`--part verify|speed|focus`). Kirchhoff plates by "
             "scikit-fem's 15-parameter nonconforming triangle on gmsh meshes, refined until the kept modes "
             "converge (Richardson's estimate of the finest mesh's error, h^2).", ""]
    v = data.get("verify")
    if v:
        lines += ["## Verification", "", "| case | mode | modalctl | reference | error |", "|---|---|---|---|---|"]
        for key, name in (("clamped_square", "clamped square, lambda (Leissa T4.23)"),
                          ("free_square", "free square nu 0.3, lambda (Leissa T4.61)")):
            for i, (a, b) in enumerate(zip(v[key]["lambda"], v[key]["leissa"])):
                lines.append(f"| {name} | {i + 1} | {a:.3f} | {b:.3f} | {100 * (a / b - 1):+.3f}% |")
        s = v["simply_supported"]
        lines += ["", f"Simply supported 100 x 70 mm glass against the analytic plate, 21 modes converged to "
                      f"{SS_TOLERANCE:.2%}: largest frequency "
                      f"error {100 * s['max_frequency_error']:.3f}%, smallest MAC {s['min_mac']:.5f} "
                      f"({s['dofs']:.0f} dofs). The free square has {v['free_square']['rigid_modes']} rigid-body "
                      f"modes, kept apart.", ""]
    s = data.get("speed")
    if s:
        lines += ["## Solve time and memory: clamped 100 x 70 x 1 mm glass, converged to 0.5%", "",
                  "| modes | element | median time (s) | peak memory (MB) | dofs | levels | finest element (mm) | "
                  "estimated error | highest mode (Hz) |", "|---|---|---|---|---|---|---|---|---|"]
        for r in s["rows"]:
            lines.append(f"| {r['modes']} | {r['element']} | {r['seconds']:.2f} | {r['memory_mb']:.0f} | {r['dofs']} | "
                         f"{r['levels']} | {r['size_mm']:.2g} | {r['error']:.3%} | {r['f_max']:.0f} |")
        lines += ["", f"Morley's triangle takes {s['ratio_morley_over_ours_30']:.1f} times as long for the same 30 "
                      f"modes to the same tolerance (same run). Memory: the solve's peak above the process's "
                      f"before it ({s['rows'][0]['process_mb']:.0f} MB with Python and the libraries).", ""]
    t = data.get("tablet")
    if t and "rows" in t:
        b, first = t["before"], t["rows"][0]
        cell = lambda x, fmt: "-" if x is None else format(x, fmt)  # noqa: E731
        lines += ["## The tablet panel (issue 36): every mode below 20 kHz", "",
                  "210 x 150 x 0.7 mm glass, 8 mm corners, clamped, eight 14 x 10 mm patches, a 1 mm grid; the "
                  "command as a user runs it, pictures and all, in a fresh process:", "", f"`{first['command']}`", "",
                  "| | wall time (s) | CPU time (s) | peak memory (MB) | dofs (finest) | modes |", "|---|---|---|---|---|---|"]
        for r in t["rows"]:
            name = " ".join(f"{k}={v}" for k, v in r["environment"].items()) or "as it starts"
            lines.append(f"| this run, {name} | {r['seconds']:.1f} | {r['cpu_seconds']:.1f} | {r['peak_mb']:.0f} | "
                         f"{r['levels_dofs'][-1] if r['levels_dofs'] else '-'} | {r['modes']} |")
        lines += [f"| {b['commit']} (before) | {cell(b['seconds'], '.1f')} | {cell(b['cpu_seconds'], '.1f')} | "
                  f"{cell(b['peak_mb'], '.0f')} | {b['dofs']} | {b['modes']} |",
                  f"| target | {t['target']['seconds']} | | {t['target']['peak_mb']} | | |", "",
                  f"Meshes of {', '.join(map(str, first['levels_dofs']))} dofs; highest mode {first['f_max']:.0f} Hz, "
                  f"estimated error {first['error']:.3%}, subspace MAC >= {first['mac']:.4f}. The machine's load "
                  f"average at the end, 1/5/15 min: {', '.join(f'{x:.1f}' for x in t['load_average_1_5_15_min'])} "
                  f"on {os.cpu_count()} cores: wall times here are what a shared machine gives; CPU time is the "
                  f"steadier measure.", ""]
    f = data.get("focus")
    if f:
        lines += ["## Focusing on finite-element plates (bump at (-20, 5) mm)", "",
                  f"Modes needed for tau >= {TAU} against the bump's width:", "",
                  "| scene | " + " | ".join(f"{w} mm" for w in WIDTHS_MM) + " |",
                  "|---|" + "---|" * len(WIDTHS_MM)]
        for scene, row in f.items():
            lines.append(f"| {scene} (of {row['of']}) | " + " | ".join("-" if n is None else str(n)
                                                                        for n in row["modes_needed"]) + " |")
        lines += ["", "A 40 mm bump on the HIL, every resonance 1% off the model (grid 51 x 36):", "",
                  "| scene | loop | exit | tau | margin ratio | peak voltage (V) | seconds |", "|---|---|---|---|---|---|---|"]
        for scene, row in f.items():
            for loop, r in row["runs"].items():
                cell = lambda x, fmt: "-" if x is None else format(x, fmt)  # noqa: E731
                lines.append(f"| {scene} | {loop} | {r['exit']} | {cell(r['tau'], '.3f')} | "
                             f"{cell(r['margin_ratio'], '.3f')} | {cell(r['peak_voltage'], '.1f')} | {r['seconds']:.0f} |")
        lines += ["", "Pictures: `fe_plate_focus_<scene>_<loop>.png` (the field on the plate around T_F)."]
    (RESULTS / "fe_plate.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    plot(data)


def plot(data: dict) -> None:
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.4))
    v = data.get("verify")
    if v:
        for name, rows in v["convergence"].items():
            dofs = [r["dofs"] for r in rows]
            err = [np.max(np.abs(np.array(r["frequencies"][:6]) * 2 * np.pi * 0.01 * np.sqrt(
                GLASS.density * 1e-3 / (GLASS.modulus * 1e-9 / (12 * (1 - GLASS.poisson**2)))) / PRECISE_CLAMPED - 1))
                   for r in rows]
            axes[0].loglog(dofs, np.array(err) * 100, "o-", label=name)
        axes[0].axhline(0.5, color="r", ls="--", lw=0.8, label="0.5%")
        axes[0].set(xlabel="degrees of freedom", ylabel="largest error, modes 1-6 (%)",
                    title="clamped square against Leissa: mesh convergence")
        axes[0].legend(fontsize=8)
    s = data.get("speed")
    if s:
        for element, marker in (("15-parameter", "o-"), ("morley", "s")):
            rows = [r for r in s["rows"] if r["element"] == element]
            axes[1].plot([r["modes"] for r in rows], [r["seconds"] for r in rows], marker, label=f"{element}: time")
        axes[1].axhline(10, color="r", ls="--", lw=0.8, label="target 10 s (30 modes)")
        axes[1].set(yscale="log", xlabel="modes converged to 0.5%", ylabel="median solve time (s)",
                    title="clamped 100 x 70 mm: time against modes kept")
        twin = axes[1].twinx()
        rows = [r for r in s["rows"] if r["element"] == "15-parameter"]
        twin.plot([r["modes"] for r in rows], [r["memory_mb"] for r in rows], "C2^--", label="memory")
        twin.set_ylabel("peak memory (MB)", color="C2")
        axes[1].legend(fontsize=8, loc="center left")
    f = data.get("focus")
    if f:
        for scene, row in f.items():
            axes[2].plot(row["widths_mm"], [np.nan if n is None else n for n in row["modes_needed"]], "o-", label=scene)
        axes[2].set(xlabel="bump width (mm)", ylabel=f"modes needed (tau >= {TAU})",
                    title="modes a 2-D bump needs (Fig 4.31, for plates)")
        axes[2].legend(fontsize=8)
    save_figure(fig, "fe_plate")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--part", choices=("verify", "speed", "tablet", "focus"), action="append")
    parser.add_argument("--report-only", action="store_true")
    args = parser.parse_args()
    try:
        data, _ = read_json("fe_plate")
    except (OSError, ValueError):
        data = {}
    if not args.report_only:
        for part in args.part or ("verify", "speed", "tablet", "focus"):
            data[part] = {"verify": part_verify, "speed": part_speed, "tablet": part_tablet, "focus": part_focus}[part]()
            write_json("fe_plate", data)
    report(data)


if __name__ == "__main__":
    main()
