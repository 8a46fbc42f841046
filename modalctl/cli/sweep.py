"""``modalctl sweep``: one focus case over a grid of scenarios on the HIL, several ways of driving
it, and maps of where each fails (sweep.json, sweep.md, maps.png in ``--out``).

The case's defaults are :class:`modalctl.experiments.sweep.Case`'s, read from it; the truth's
options a case takes (``--drift``, ``--damping-error``, ``--finger``, ``--snr``, ``--seed``) are
declared by the ``sim`` transport (hook ``modalctl_add_options``) and reused here at the case's
defaults.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from modalctl.options import LoopOptions
from modalctl.units import number_type, quantity_type

from .common import identity, identity_defaults, jsonable, out_dir, parse_param, points, progress_bars, stage, \
    write_json
from .run import voltage_limit

CASES_MAX = 10_000  # cases a sweep runs at most (a 100 x 100 map; at 5-10 s a case, a day of shots)
NAME, HELP = "sweep", "run a focus case over a grid of scenarios on the HIL and map where methods fail"

# swept parameter (an option of modalctl run, whose type reads and checks each value) -> Case field
SWEPT = {"drift": "drift", "damping-error": "damping_error", "finger": "finger", "latency": "latency",
         "snr": "snr_db", "focus-time": "focus_time", "seed": "seed"}
# the simulator's options (their dest) a case takes, and its field for each; it takes none of the others
TRUTH = {"drift": "drift", "damping_error": "damping_error", "finger": "finger", "snr": "snr_db", "seed": "seed"}


def add_parser(sub):
    return sub.add_command(NAME, HELP, add_arguments, run)


def add_arguments(p) -> None:
    from modalctl.experiments.sweep import METHODS, Case

    case = Case()  # the defaults
    p.add_argument("--scene", default=case.scene, help=f"scene (default {case.scene})")
    p.add_argument("--points", type=points,
                   help=f"grid points: N for a beam (default {case.points}), NxM for a plate (default: the scene's)")
    p.add_argument("--shape", default=case.shape, help=f"shape generator ({case.shape})")
    p.add_argument("--param", action="append", default=[], type=parse_param, metavar="NAME=VALUE",
                   help="shape parameter with units (default " + " ".join(f"{k}={v}" for k, v in case.params) + ")")
    p.add_argument("--focus-time", type=quantity_type("s", "focus-time", low=0), default=case.focus_time,
                   help=f"T_F ({case.focus_time * 1e3:g}ms)")
    p.add_argument("--planner", default=case.planner,
                   help=f"planner plugin ({case.planner}: the sweeps measure the loops on the thesis's plan)")
    p.add_argument("--margin", type=quantity_type("1", "margin", low=0, high=1), default=case.margin,
                   help="transient margin to plan for")
    p.add_argument("--tau-target", type=number_type(float, "tau-target", low=0, high=1),
                   help="least tau of the automatic mode set and of a finite-element plate's grown model (0.98), "
                        "as run's")
    p.add_argument("--voltage-limit", type=voltage_limit,
                   help="largest drive voltage, e.g. 100V, or none; default: the model's actuators' safe voltage, "
                        "as run's")
    p.add_argument("--vary", action="append", default=[], type=parse_param, metavar="NAME=V1,V2,...",
                   help="a swept parameter and its values: " + ", ".join(SWEPT) + " (one or two)")
    p.add_argument("--methods", default=",".join(METHODS[:3]),
                   help=", ".join(METHODS) + " (default the first three)")
    p.add_argument("--control-rate", type=quantity_type("Hz", "control-rate", low=0), default=case.control_rate,
                   help=f"loop rate ({case.control_rate / 1e3:g}kHz)")
    p.add_argument("--sample-rate", type=quantity_type("Hz", "sample-rate", low=0), default=case.sample_rate,
                   help=f"DAC rate ({case.sample_rate / 1e3:g}kHz)")
    p.add_argument("--controller", default=case.controller,
                   help=f"per-mode controller plugin of the closed loops ({LoopOptions().chosen_controller})")
    p.add_argument("--scheduler", help="dask.distributed scheduler address (default: a local process pool)")
    p.add_argument("--workers", type=number_type(int, "workers", low=1, high=256, low_open=False),
                   help="local processes (default: every core)")
    _add_truth_arguments(p, case)
    p.add_argument("--out", required=True, type=out_dir, help="directory for sweep.json, sweep.md and maps.png")
    p.add_argument("--force", action="store_true", help="replace another run's results in --out")
    p.add_argument("--json", action="store_true")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _swept_values(name: str, text: str) -> tuple[str, list]:
    """A swept option's field and values, each read and checked by the type ``modalctl run`` reads
    the option with (its unit, its range, a finite number): a sweep never reaches a value a run refuses."""
    from modalctl.model.shape import ParamError

    from .common import option_type

    if name not in SWEPT:
        raise ParamError(f"cannot sweep {name!r}; choose from {', '.join(SWEPT)}")
    read, values = option_type("run", f"--{name}"), []
    for item in text.split(","):
        try:
            values.append(read(item.strip()))
        except argparse.ArgumentTypeError as exc:  # its message names the option, the range and the value
            raise ParamError(f"--vary {exc}") from None
        except ValueError:  # a plain number's type: argparse would say "invalid <name> value"
            raise ParamError(f"--vary {name}: expected numbers separated by commas, got {item.strip()!r}") from None
    return SWEPT[name], values


def _add_truth_arguments(p, case) -> None:
    """The simulator's own options a case takes (``TRUTH``), as the ``sim`` transport declares them
    (hook ``modalctl_add_options``: names, units, bounds, help), at the case's defaults."""
    from modalctl.io.device import add_transport_options

    declared = add_transport_options(argparse.ArgumentParser(add_help=False))  # every transport's, set aside
    group = p.add_argument_group("the truth, fixed when not swept (the simulator's options)")
    for action in declared.parser._actions:
        if declared.owners.get(action.dest) == "sim" and action.dest in TRUTH:
            default = getattr(case, TRUTH[action.dest])
            said = action.help if default == action.default else f"{action.help} ({default:g})"  # a sweep's own
            group.add_argument(*action.option_strings, dest=action.dest, type=action.type, default=default,
                               metavar=action.metavar, help=said)


def _cases(args, axes: list, methods: list) -> list:
    """Every case of the sweep: each method at each point of the swept axes."""
    import itertools
    from dataclasses import replace

    from modalctl.experiments.sweep import Case
    from modalctl.model.scenes import SCENES, load_scene
    from modalctl.plugin.manager import get_controller, get_planner, get_shape

    truth = {field: getattr(args, dest) for dest, field in TRUTH.items()}
    get_shape(args.shape)  # a clear error before any work
    get_planner(args.planner)
    if args.points is None and args.scene in SCENES and isinstance(SCENES[args.scene].default_points, int):
        args.points = Case.points  # a beam: a fifth of the scenes' grids draws their modes and runs five times faster
    model = load_scene(args.scene, args.points)
    volts = None if args.voltage_limit == "none" else args.voltage_limit or model.voltage_limit
    base = Case(args.scene, args.shape, tuple(args.param) or Case.params, args.focus_time, "open", planner=args.planner,
                margin=args.margin, points=args.points, control_rate=args.control_rate,
                sample_rate=args.sample_rate, controller=LoopOptions(controller=args.controller).chosen_controller,
                voltage_limit=volts, tau_target=args.tau_target, **truth)
    get_controller(base.controller)
    return [replace(base, method=m, **dict(zip([f for f, _ in axes], values)))
            for m in methods for values in itertools.product(*[v for _, v in axes])]


def run(args) -> int:
    from modalctl.experiments.executor import executor_for
    from modalctl.experiments.sweep import METHODS, run_case
    from modalctl.loops.realtime import keep_memory
    from modalctl.model.shape import ParamError
    from modalctl.outdir import claim

    keep_memory()  # shots reuse their memory instead of faulting on fresh pages each time
    if not 1 <= len(args.vary) <= 2:
        raise ParamError("give one or two --vary NAME=V1,V2,... (e.g. --vary drift=0,1%,2%)")
    names = [name for name, _ in args.vary]
    if len(set(names)) < len(names):
        raise ParamError(f"--vary {names[0]} given twice: one axis a name, two names at most")
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    unknown = set(methods) - set(METHODS)
    if unknown or not methods:
        said = f"unknown method(s) {', '.join(sorted(unknown))}" if unknown else "--methods: none given"
        raise ParamError(f"{said}; choose from {', '.join(METHODS)}")
    axes = [_swept_values(name, text) for name, text in args.vary]
    count = len(methods) * math.prod(len(values) for _, values in axes)
    if count > CASES_MAX:  # before any case is made: 15,000 seeds by 15,000 ratios had built 2.7 GB of them
        raise ParamError(f"{count} cases ({' x '.join(str(len(v)) for _, v in axes)} values, {len(methods)} methods); "
                         f"a sweep runs {CASES_MAX} at most: split it")
    cases = _cases(args, axes, methods)
    for case in cases:  # each shot's options checked before --out is claimed (a 10 s focus, a rate not dividing)
        case.options()
    out = claim(Path(args.out), "sweep", identity(args), args.force, identity_defaults("sweep"))
    executor = executor_for(args.scheduler, args.workers)
    stage(args, f"{len(cases)} cases ({type(executor).__name__})")
    rows = executor.map(run_case, cases, progress=progress_bars(args))
    stage(args, f"the report into {out}/")
    summary = {"axes": {f: v for f, v in axes}, "methods": methods, "rows": rows,
               "executor": type(executor).__name__}
    write_json(out / "sweep.json", summary)
    _report(args, summary, rows, out, [f for f, _ in axes])
    return 0


def _report(args, summary: dict, rows: list, out: Path, fields: list) -> None:
    """sweep.md and maps.png beside sweep.json; the table (or the summary as JSON) on stdout."""
    from modalctl.outdir import atomic, record
    from modalctl.report import plot_sweep_maps, sweep_table

    refused = [f"- {r['method']}, " + ", ".join(f"{f} {r[f]:g}" for f in fields) + f": {r['fault']}"
               for r in rows if r["state"] == "refused"]  # run_case's rows of a shot that was refused
    with atomic(out / "sweep.md") as temporary:
        temporary.write_text(sweep_table(rows, fields) + ("\nRefused (no shot played):\n" + "\n".join(refused) + "\n"
                                                          if refused else ""))
    record(out, ["maps.png"])
    summary["pictures"] = {"maps": str(plot_sweep_maps(rows, fields, summary["methods"], out / "maps.png"))}
    if args.json:
        print(json.dumps(summary, default=jsonable))
    else:
        print((out / "sweep.md").read_text())
        print(f"report: {out}/ (sweep.json, sweep.md, maps.png)")
