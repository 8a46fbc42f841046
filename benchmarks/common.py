"""Shared pieces of the benchmarks: medians, the results folder, machine facts, a thesis scene's target."""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"


#: The tablet panel of issue 36: 210 x 150 x 0.7 mm glass, 8 mm corners, clamped, eight 14 x 10 mm
#: patches (centres in mm), every mode below 20 kHz. The patches sit off the panel's two mirror axes:
#: placed mirror-symmetrically (x = +-25, +-75 mm, y = +-55 mm) they pushed each symmetry class's
#: modes along two directions in all (31 close pairs at |cos| >= 0.99, 18,687 and 18,712 Hz among
#: them), and a 20 mm bump's least-energy drive drove those pairs to 44 times its largest target to
#: tell them apart: 4.4 times over the margin, its program never done in 6 minutes. Scattered off
#: the axes (below), the same bump's least-energy drive holds 0.39 at once (issue 36's notes;
#: ``modalctl.model.actuation``).
TABLET_PATCH_CENTRES_MM = [(-78, -52), (-31, -52), (17, -52), (66, -52), (-69, 57), (-22, 57), (28, 57), (79, 57)]


def tablet_arguments(out) -> list[str]:
    """``model fe``'s arguments for the tablet panel (above), its model written to ``out``."""
    patches = [f"--patch={x - 7}mm,{x + 7}mm,{y - 5}mm,{y + 5}mm" for x, y in TABLET_PATCH_CENTRES_MM]
    return ["model", "fe", "--outline", "rect:210mm,150mm,r=8mm", "--thickness", "0.7mm", "--material", "glass",
            "--boundary", "clamped", *patches, "--sensor", "0,0", "--band", "20kHz", "--out", str(out)]


def median_seconds(func, repeats: int) -> float:
    """Median wall time of ``repeats`` calls (s)."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        func()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def machine() -> dict:
    """What the numbers were measured on (the load average when they were written: the benchmark's
    own process counts about one; more says something else shared the machine's cores)."""
    import casadi
    import control
    import scipy

    return {"python": platform.python_version(), "numpy": np.__version__, "scipy": scipy.__version__,
            "control": control.__version__, "casadi": casadi.__version__, "machine": platform.machine(),
            "cpu": cpu_model(), "cpus": os.cpu_count(), "load_average_1_5_15_min": list(os.getloadavg()),
            "speed": speed_probe()}


def cpu_model() -> str:
    """The processor's name (Linux's /proc/cpuinfo; the platform's otherwise): BLAS picks its kernels by
    it, and an ill-conditioned computation's last bits with them (docs/identification.md)."""
    try:
        with open("/proc/cpuinfo") as info:
            return next(line.split(":", 1)[1].strip() for line in info if line.startswith("model name"))
    except (OSError, StopIteration):
        return platform.processor() or "unknown"


def speed_probe() -> dict:
    """Seconds this machine takes, now, for a fixed interpreter loop (10^7 additions) and a fixed
    BLAS product (five 1000 x 1000 matrix squares), medians of three: the scale against which
    one run's seconds compare with another's (the loop took 1.48 s and 0.64 s on this 2-core machine
    twenty minutes apart, 2026-11-28: it is shared)."""
    a = np.random.default_rng(0).random((1000, 1000))

    def loop():
        total = 0
        for i in range(10**7):
            total += i
        return total

    return {"python_loop_s": median_seconds(loop, 3),
            "matmul_s": median_seconds(lambda: [a @ a for _ in range(5)], 3)}


def write_json(name: str, data: dict) -> Path:
    RESULTS.mkdir(exist_ok=True)
    path = RESULTS / f"{name}.json"
    path.write_text(json.dumps({**data, "machine": machine()}, indent=2, default=float))
    return path


def read_json(name: str) -> tuple[dict, Path]:
    """The last run's ``results/<name>.json`` and its path (to redraw a report without running)."""
    path = RESULTS / f"{name}.json"
    return json.loads(path.read_text()), path


def command_line(flags: dict | None = None, reports: bool = False) -> argparse.Namespace:
    """The running benchmark's command line: ``--help`` says its docstring, ``--report-only`` where
    it can redraw from its last JSON (``reports``), ``flags`` its own (``{"--name": argparse's
    keywords}``); anything else is refused with exit 2. Unparsed, ``finger.py --help`` ran the whole
    benchmark (six minutes) and a mistyped flag was ignored."""
    import __main__

    parser = argparse.ArgumentParser(description=getattr(__main__, "__doc__", None),
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    if reports:
        parser.add_argument("--report-only", action="store_true", help="redraw from the last run's JSON in results/")
    for flag, keywords in (flags or {}).items():
        parser.add_argument(flag, **keywords)
    return parser.parse_args()


def main_or_report(name: str, main, report) -> None:
    """A benchmark's entry point: ``main()``, or with ``--report-only`` its ``report(data, path)``
    redrawn from the last run's ``results/<name>.json`` (:func:`command_line`)."""
    if command_line(reports=True).report_only:
        report(*read_json(name))
    else:
        main()


def write_markdown(name: str, lines: list[str], json_path: Path | None = None) -> Path:
    """Write ``results/<name>.md`` from ``lines``, print it, and say where the results are."""
    RESULTS.mkdir(exist_ok=True)
    path = RESULTS / f"{name}.md"
    text = "\n".join(lines)
    path.write_text(text)
    print(text)
    print(f"wrote {json_path or path}")
    return path


def save_figure(fig, name: str, dpi: int = 120, rect=(0, 0, 1, 1)) -> Path:
    """Lay out (the axes within ``rect``, figure fractions: room for a figure legend), write
    ``results/<name>.png`` and close the figure."""
    import matplotlib.pyplot as plt

    RESULTS.mkdir(exist_ok=True)
    path = RESULTS / f"{name}.png"
    fig.tight_layout(rect=rect)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


def state_space(model):
    """The model as python-control's modal state space (the peers' form): states (eta, eta'),
    inputs the actuators' voltages, outputs every mode's velocity eta'."""
    import control

    k = model.n_modes
    a = np.block([[np.zeros((k, k)), np.eye(k)], [-np.diag(model.omega**2), -np.diag(2 * model.damping * model.omega)]])
    b = np.vstack([np.zeros_like(model.actuator_gains), model.actuator_gains])
    c = np.hstack([np.zeros((k, k)), np.eye(k)])
    return control.ss(a, b, c, np.zeros((k, b.shape[1])))


def target(model, shape: str, **params):
    """A shape generator's field on the model's grid; ``params`` as text with units."""
    from modalctl.model.shape import parse_params
    from modalctl.plugin.manager import get_shape

    generator = get_shape(shape)
    return generator.generate(model.grid, **parse_params(generator, params))


def open_loop(model, shape, device, focus_time: float, **plan):
    """An open-loop shot through :func:`modalctl.run.run`, the path ``modalctl run`` takes, with the
    plan options ``plan`` (:class:`modalctl.options.PlanOptions`' fields, over the thesis's method
    :data:`modalctl.options.THESIS_PLAN`); its :class:`modalctl.run.ShotResult`."""
    from modalctl.options import THESIS_PLAN, RunOptions
    from modalctl.run import run

    return run(model, shape, device, RunOptions(focus_time, THESIS_PLAN.but(**plan)))
