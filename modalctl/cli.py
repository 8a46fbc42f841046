"""The ``modalctl`` command: ``scenes``, ``plugins``, ``decompose``, ``identify``, ``run``, ``sweep``, ``emulate``,
``model fe``.

Exit codes: 0 success, 1 a target that cannot be met (no mode set or no plan meets it: the
message says by how much), 2 bad input (unknown scene, shape or parameter, bad units,
unreadable file), 3 a device error or a closed-loop shot stopped by the supervisor.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import json
import math
import re
import sys
from pathlib import Path

from modalctl.hil.scenario import DAMPING_ERROR_MAX, DRIFT_MAX, SNR_MAX
from modalctl.io.device import DeviceContext, DeviceError, add_transport_options
from modalctl.loops.realtime import keep_memory
from modalctl.model.modes import ModalModel, ModelError
from modalctl.model.scenes import SCENES, UnknownScene, load_scene
from modalctl.model.shape import ParamError, parse_params
from modalctl.options import (
    LEARN_FROM,
    ROBUST_DRIFT_MAX,
    THESIS_PLAN,
    LoopOptions,
    PlanOptions,
    RunOptions,
    SurveyOptions,
)
from modalctl.plan.decompose import decompose
from modalctl.plan.planner import PlanError
from modalctl.plan.reduction import ReductionError
from modalctl.plugin.manager import PluginError, get_controller, get_planner, get_shape, plugin_table, shape_generators

from .outdir import atomic, claim, record
from .units import UnitError, number_type, parse_quantity, quantity_type

BAD_INPUT, UNREACHABLE, DEVICE = 2, 1, 3
POINTS_MAX = 1_000_000  # grid points of a scene (a 1000 x 1000 plate)
MODES_MAX = 1000
SCAN_POINTS_MIN = 5  # identify: scan points a mode shape needs
SEED = number_type(int, "seed", low=0, high=2**32 - 1, low_open=False)
PLAN, LOOP, SURVEY = PlanOptions(), LoopOptions(), SurveyOptions()  # the defaults the options below show and use
REAL_TIME = {"run", "sweep", "emulate"}  # the commands that play shots (see modalctl.loops.realtime)


def _parse_param(text: str) -> tuple[str, str]:
    if "=" not in text:
        raise argparse.ArgumentTypeError(f"expected name=value, got {text!r}")
    name, value = text.split("=", 1)
    return name.strip(), value.strip()


NEGATIVE = re.compile(r"^-\.?\d")  # a value, not an option: -1%, -30mm, -.5


def _points(text: str):
    """Grid points: ``211`` for a beam, ``101x71`` (or ``101,71``) for a plate."""
    try:
        parts = [int(v) for v in text.lower().replace("x", ",").split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"points: expected N (a beam) or NxM (a plate), got {text!r}") from None
    if len(parts) > 2 or min(parts) < 2 or math.prod(parts) > POINTS_MAX:
        raise argparse.ArgumentTypeError(f"points: N or NxM with at least 2 per side and at most {POINTS_MAX:,} "
                                         f"in all, got {text!r}")
    return parts[0] if len(parts) == 1 else tuple(parts)


def _add_target(p) -> None:
    """Arguments shared by decompose and run: where the model and the shape come from."""
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--scene", help="scene name (see 'modalctl scenes')")
    source.add_argument("--model", help="modal model file (.npz written by modalctl)")
    p.add_argument("--shape", required=True, help="shape generator (see 'modalctl plugins')")
    p.add_argument("--param", action="append", default=[], type=_parse_param, metavar="NAME=VALUE",
                   help="shape parameter with units, e.g. width=18mm (repeatable)")
    p.add_argument("--modes", type=_modes, default="auto",
                   help="auto (smallest set meeting the target), all, or N (the N lowest modes)")
    p.add_argument("--tau-target", type=number_type(float, "tau-target", low=0, high=1),
                   help="auto: least tau for the kept modes (default 0.98)")
    p.add_argument("--points", type=_points, help="grid points: N for a beam, NxM for a plate (default: the scene's)")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def _modes(text: str):
    if text in ("auto", "all"):
        return text
    try:
        count = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected auto, all or a number of modes, got {text!r}") from None
    if not 1 <= count <= MODES_MAX:
        raise argparse.ArgumentTypeError(f"modes must lie in [1, {MODES_MAX}], got {text!r}")
    return count


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="modalctl", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    parser.commands = sub.choices  # each command's parser, by name (its defaults: _identity_defaults)

    p = sub.add_parser("scenes", help="list the named scenes")
    p.add_argument("--json", action="store_true")

    p = sub.add_parser("plugins", help="list installed plugins and shape generators")
    p.add_argument("--json", action="store_true")

    p = sub.add_parser("decompose", help="project a target field on a scene's modes and reduce")
    _add_target(p)
    p.add_argument("--nrmse-target", type=number_type(float, "nrmse-target", low=0),
                   help="auto: largest NRMSE for the kept modes")
    p.add_argument("--orthogonalize", action="store_true", help="Gram-Schmidt the mode shapes first")
    p.add_argument("--plot", metavar="FILE.png", help="draw the field and the modal bars")
    p.add_argument("--save-model", metavar="FILE.npz", help="also write the model used")

    p = sub.add_parser("run", help="plan a focus, play it on a device (default sim://) and measure it")
    _add_target(p)
    p.add_argument("--focus-time", required=True, type=quantity_type("s", "focus-time", low=0), help="T_F, e.g. 25ms")
    p.add_argument("--planner", default=PLAN.planner,
                   help="planner plugin; convex: the least-energy drive that holds the margin on every sample of "
                        f"the whole model (a QP); envelope: the thesis's exponential envelopes ({PLAN.planner})")
    p.add_argument("--margin", type=_margin, default=PLAN.margin,
                   help="transient margin off target, before and after T_F, as a share of the focus peak, "
                        f"e.g. 0.5 or 50%%, or none ({_margin_words(PLAN.margin)})")
    p.add_argument("--robust-drift", type=quantity_type("1", "robust-drift", low=0, high=ROBUST_DRIFT_MAX,
                                                        low_open=False),
                   default=PLAN.robust_drift,
                   help="convex planner: hold the margin on every truth whose resonances lie within this band "
                        "of the model's, e.g. 1%% (0)")
    p.add_argument("--voltage-limit", type=quantity_type("V", "voltage-limit", low=0),
                   help="largest drive voltage, e.g. 100V")
    p.add_argument("--slew-limit", type=quantity_type("V/s", "slew-limit", low=0),
                   help="largest output slope, e.g. 2e6V/s: planned for by the convex planner, and the "
                        "closed loop's feedback clipped to it")
    p.add_argument("--margin-on", choices=("whole", "kept"), default=PLAN.margin_on,
                   help="where --margin must hold: whole (the field the voltages drive on every mode of the "
                        "model; they are corrected near the focus until it does, up to a minute) or kept (the "
                        "kept modes' references, the thesis's criterion)")
    p.add_argument("--kappa", type=number_type(float, "kappa", low=0), default=PLAN.kappa,
                   help=f"envelope rate without --margin ({PLAN.kappa:g})")
    p.add_argument("--no-brake", action="store_true", help="optimizer: free decay after the focus only")
    p.add_argument("--after", type=quantity_type("s", "after", low=0), default=PLAN.after,
                   help=f"post-transient window recorded and checked ({PLAN.after * 1e3:g}ms)")
    p.add_argument("--sample-rate", type=quantity_type("Hz", "sample-rate", low=0), default=PLAN.sample_rate,
                   help=f"DAC rate ({PLAN.sample_rate / 1e6:g}MHz)")
    p.add_argument("--transport", default="sim://", help="device URL (default sim://)")
    loop = p.add_argument_group("closed loop")
    loop.add_argument("--loop", choices=("open", "closed", "board"), default="open",
                      help="open: feed-forward only (the thesis); closed: per-mode feedback on top, one "
                           "exchange with the board per period; board: the same PI loops loaded into the board, "
                           "which closes them itself (no link budget)")
    loop.add_argument("--control-rate", type=quantity_type("Hz", "control-rate", low=0), default=LOOP.control_rate,
                      help=f"loop rate, a divisor of the sample rate ({LOOP.control_rate / 1e3:g}kHz)")
    loop.add_argument("--authority", type=number_type(float, "authority", low=0, low_open=False),
                      default=LOOP.authority,
                      help=f"largest feedback per mode, as a fraction of its planned drive ({LOOP.authority:g})")
    loop.add_argument("--latency", type=number_type(int, "latency", low=0, high=1000, low_open=False), default=LOOP.latency,
                      help=f"extra periods the board takes to use a command ({LOOP.latency})")
    loop.add_argument("--controller", default=LOOP.controller,
                      help=f"per-mode controller plugin: pi, lqg, or touch (pi plus the force a finger takes, "
                           f"estimated during the shot) ({LOOP.controller})")
    loop.add_argument("--touch-at", type=quantity_type("m", "touch-at", point=True), metavar="POINT",
                      help="touch controller: where a touch sensor says the finger rests, e.g. 0mm (default: "
                           "the controller finds it)")
    loop.add_argument("--watchdog", type=number_type(int, "watchdog", low=1, high=10**6, low_open=False), default=LOOP.watchdog,
                      help=f"periods without a measurement before the supervisor stops the shot ({LOOP.watchdog})")
    loop.add_argument("--learn", nargs="?", const="record", choices=LEARN_FROM,
                      help="a first closed-loop shot teaches the model: from its record (record, the default: "
                           "every resonance and damping fitted to it) or from a pole tracker during it (tracker); "
                           "the shot planned again on the updated model is the one reported")
    p.set_defaults(transports=add_transport_options(p))
    p.add_argument("--out", required=True, type=_out_dir,
                   help="directory for metrics.json, fields.npz and the pictures")
    p.add_argument("--force", action="store_true", help="replace another run's results in --out")
    p.add_argument("--no-plots", action="store_true")
    p.add_argument("--quiet", action="store_true", help="no progress bar")

    p = sub.add_parser("sweep", help="run a focus case over a grid of scenarios on the HIL and map where methods fail")
    p.add_argument("--scene", default="thesis-al-cc", help="scene (default thesis-al-cc)")
    p.add_argument("--points", type=_points,
                   help="grid points: N for a beam (default 211), NxM for a plate (default: the scene's)")
    p.add_argument("--shape", default="sinc", help="shape generator (sinc)")
    p.add_argument("--param", action="append", default=[], type=_parse_param, metavar="NAME=VALUE",
                   help="shape parameter with units (default width=18mm center=24mm)")
    p.add_argument("--focus-time", type=quantity_type("s", "focus-time", low=0), default=25e-3, help="T_F (25ms)")
    p.add_argument("--planner", default=THESIS_PLAN.planner,
                   help=f"planner plugin ({THESIS_PLAN.planner}: the sweeps measure the loops on the thesis's plan)")
    p.add_argument("--margin", type=quantity_type("1", "margin", low=0, high=1),
                   help="transient margin to plan for")
    p.add_argument("--vary", action="append", default=[], type=_parse_param, metavar="NAME=V1,V2,...",
                   help="a swept parameter and its values: " + ", ".join(SWEPT) + " (one or two)")
    p.add_argument("--methods", default="open,closed,tracked",
                   help="open, closed, tracked, learned (default the first three)")
    p.add_argument("--drift", type=quantity_type("1", "drift", low=-DRIFT_MAX, high=DRIFT_MAX), default=0.0,
                   help="fixed drift when not swept")
    p.add_argument("--damping-error", type=quantity_type("1", "damping-error", low=-1, high=DAMPING_ERROR_MAX),
                   default=0.0)
    p.add_argument("--snr", type=number_type(float, "snr", low=0, high=SNR_MAX, low_open=False), default=40.0,
                   help="sensor noise, dB below the focus peak (40)")
    p.add_argument("--control-rate", type=quantity_type("Hz", "control-rate", low=0), default=20e3)
    p.add_argument("--sample-rate", type=quantity_type("Hz", "sample-rate", low=0), default=500e3)
    p.add_argument("--controller", default="pi", help="per-mode controller plugin of the closed loops (pi)")
    p.add_argument("--seed", type=SEED, default=0)
    p.add_argument("--scheduler", help="dask.distributed scheduler address (default: a local process pool)")
    p.add_argument("--workers", type=number_type(int, "workers", low=1, high=256, low_open=False), help="local processes (default: every core)")
    p.add_argument("--out", required=True, type=_out_dir, help="directory for sweep.json, sweep.md and maps.png")
    p.add_argument("--force", action="store_true", help="replace another run's results in --out")
    p.add_argument("--json", action="store_true")
    p.add_argument("--quiet", action="store_true", help="no progress bar")

    p = sub.add_parser("emulate", help="serve the HIL board on a serial device path (a pty) until interrupted")
    p.add_argument("--scene", default="thesis-al-cc", help="the structure (thesis-al-cc)")
    p.add_argument("--points", type=_points, help="grid points: N for a beam, NxM for a plate (default: the scene's)")
    p.set_defaults(transports=add_transport_options(p))
    p.add_argument("--latency", type=number_type(int, "latency", low=0, high=1000, low_open=False), default=0,
                   help="extra periods before a command is used")
    p.add_argument("--for", dest="seconds", type=quantity_type("s", "for", low=0), help="stop after this long (default: never)")

    p = sub.add_parser("identify", help="identify a structure's modes from FRFs measured through a device")
    p.add_argument("--transport", default="sim://", help="device URL (default sim://)")
    p.add_argument("--scene", help="sim://: the structure simulated (and its mass per length by default)")
    p.add_argument("--frf", help="identify from measured FRFs in a universal file (datasets 58 and 15) instead")
    p.set_defaults(transports=add_transport_options(p), snr=40.0)  # a vibrometer of 40 dB, unless said
    p.add_argument("--f-low", type=quantity_type("Hz", "f-low", low=0, low_open=False), default=100.0, help="sweep start (100Hz)")
    p.add_argument("--f-high", type=quantity_type("Hz", "f-high", low=0), default=100e3, help="sweep end (100kHz)")
    p.add_argument("--resolution", type=quantity_type("Hz", "resolution", low=0), default=4.0,
                   help="FRF resolution = 1 / T_sweep (4Hz)")
    p.add_argument("--amplitude", type=quantity_type("V", "amplitude", low=0), default=15.0,
                   help="sweep peak voltage (15V)")
    p.add_argument("--step", type=quantity_type("m", "step", low=0), default=1e-3,
                   help="spatial step of the scan, in each direction on a plate (1mm)")
    p.add_argument("--mass-per-length", type=quantity_type("kg/m", "mass-per-length", low=0),
                   help="of a beam (kg/m); default from the scene")
    p.add_argument("--mass-per-area", type=quantity_type("kg/m^2", "mass-per-area", low=0),
                   help="of a plate (kg/m^2); default from the scene")
    p.add_argument("--method", default=SURVEY.method, help=f"identifier plugin: auto, sdof, mdof or peaks (see 'modalctl plugins'; {SURVEY.method})")
    p.add_argument("--primary", type=number_type(int, "primary", low=0, low_open=False), default=SURVEY.primary,
                   help=f"actuator swept over the whole grid ({SURVEY.primary})")
    p.add_argument("--averages", type=number_type(int, "averages", low=1, high=1000, low_open=False), default=SURVEY.averages,
                   help=f"shots per point ({SURVEY.averages})")
    p.add_argument("--no-orthogonalize", action="store_true", help="skip Gram-Schmidt")
    p.add_argument("--out", required=True, help="model file to write (.npz); pictures beside it")
    p.add_argument("--no-plots", action="store_true")
    p.add_argument("--json", action="store_true")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_model_parser(sub)
    return parser


FE_HOLES_MAX, FE_PATCHES_MAX, FE_SENSORS_MAX = 20, 32, 32


def _add_model_parser(sub) -> None:
    """``modalctl model fe``: a plate's modal model by finite elements, from its geometry."""
    model = sub.add_parser("model", help="build a modal model from a structure's geometry")
    kinds = model.add_subparsers(dest="kind", required=True)
    p = kinds.add_parser("fe", help="a Kirchhoff plate of any outline by finite elements (scikit-fem, gmsh)",
                         description="Outline, holes, supports, material, patches and sensors in; the lowest modes "
                                     "out, refined until they converge, as a model file every command takes "
                                     "(--model).")
    p.add_argument("--outline", required=True, type=_fe_outline,
                   help="rect:W,H[,r=R] (centred on the origin) or polygon:X,Y;X,Y;... (units, e.g. 100mm)")
    p.add_argument("--hole", action="append", default=[], type=_fe_hole,
                   help="circle:X,Y,R or rect:X,Y,W,H[,r=R] (centre, size; repeatable; its edge is free)")
    p.add_argument("--thickness", required=True, type=quantity_type("m", "thickness", low=0, high=0.1))
    p.add_argument("--material", default="glass", type=_fe_material,
                   help="glass, aluminium, steel, pmma, polycarbonate or E=70GPa,rho=2500kg/m^3,nu=0.22 (glass)")
    p.add_argument("--boundary", default={}, type=_fe_supports,
                   help="clamped, simply-supported, free or elastic:k=1MN/m^2:kr=1N for the rim, or per edge: "
                        "rim=clamped,left=free,holes=free (edges: rim, holes, edge1.., and bottom/right/top/left of "
                        "a rectangle; default clamped rim, free holes)")
    p.add_argument("--patch", action="append", default=[], type=_fe_patch,
                   help="piezo patch on the back: X0,X1,Y0,Y1 (repeatable)")
    p.add_argument("--sensor", action="append", default=[], type=_fe_sensor, help="velocity sensor X,Y (repeatable)")
    count = p.add_mutually_exclusive_group(required=True)
    count.add_argument("--modes", type=number_type(int, "modes", low=1, high=500, low_open=False),
                       help="the N lowest modes")
    count.add_argument("--band", type=quantity_type("Hz", "band", low=0, high=1e6),
                       help="every mode below this frequency (the band the drive can excite)")
    p.add_argument("--tolerance", type=quantity_type("1", "tolerance", low=1e-5, high=0.2, low_open=False),
                   default=0.005, help="kept modes' frequencies converged to this (0.5%%)")
    p.add_argument("--spacing", type=quantity_type("m", "spacing", low=1e-4, high=0.1, low_open=False),
                   default=1e-3, help="focus grid spacing (1mm)")
    p.add_argument("--damping", type=quantity_type("1", "damping", low=0, high=0.5), default=0.01,
                   help="modal damping ratio of every mode (1%%)")
    p.add_argument("--out", required=True, help="model file to write (.npz); pictures beside it")
    p.add_argument("--no-plots", action="store_true")
    p.add_argument("--json", action="store_true")
    p.add_argument("--quiet", action="store_true", help="no progress lines")


def _fe_spec(text: str, kinds: tuple[str, ...], what: str) -> tuple[str, str]:
    kind, _, rest = text.partition(":")
    if kind not in kinds or not rest:
        raise argparse.ArgumentTypeError(f"{what}: expected {' or '.join(k + ':...' for k in kinds)}, got {text!r}")
    return kind, rest


def _fe_lengths(text: str, count: int, what: str) -> tuple[list[float], float]:
    """``count`` comma-separated lengths and an optional ``r=R``, in metres."""
    parts = [v.strip() for v in text.split(",")]
    radius = [v for v in parts if v.startswith("r=")]
    values = [v for v in parts if not v.startswith("r=")]
    if len(values) != count or len(radius) > 1:
        raise argparse.ArgumentTypeError(f"{what}: expected {count} lengths (and r=R), got {text!r}")
    try:
        lengths = [parse_quantity(v, "m", what) for v in values]
        r = parse_quantity(radius[0][2:], "m", what) if radius else 0.0
    except UnitError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return lengths, r


def _fe_outline(text: str):
    import numpy as np

    from modalctl.model.fe_plate import Outline

    kind, rest = _fe_spec(text, ("rect", "polygon"), "outline")
    try:
        if kind == "rect":
            (a, b), r = _fe_lengths(rest, 2, "outline")
            return Outline.rectangle(a, b, r)
        corners = rest.split(";")
        if not 3 <= len(corners) <= 1000:
            raise argparse.ArgumentTypeError(f"outline: a polygon needs 3 to 1000 vertices, got {len(corners)}")
        return Outline(np.array([_fe_lengths(c, 2, "outline")[0] for c in corners]))
    except ModelError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _fe_hole(text: str):
    from modalctl.model.fe_plate import Hole

    kind, rest = _fe_spec(text, ("circle", "rect"), "hole")
    try:
        if kind == "circle":
            (x, y, r), _ = _fe_lengths(rest, 3, "hole")
            return Hole((x, y), radius=r)
        (x, y, w, h), r = _fe_lengths(rest, 4, "hole")
        return Hole((x, y), size=(w, h), corner_radius=r)
    except ModelError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _fe_material(text: str):
    from modalctl.model.fe_plate import MATERIALS, Material

    if text in MATERIALS:
        return MATERIALS[text]
    fields = dict(_parse_param(part) for part in text.split(","))
    if set(fields) != {"E", "rho", "nu"}:
        raise argparse.ArgumentTypeError(f"material: one of {', '.join(MATERIALS)} or E=..,rho=..,nu=.., got {text!r}")
    try:
        return Material(parse_quantity(fields["E"], "Pa", "E"), parse_quantity(fields["rho"], "kg/m^3", "rho"),
                        parse_quantity(fields["nu"], "1", "nu"))
    except (UnitError, ModelError) as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _fe_support(text: str):
    from modalctl.model.fe_plate import Support

    kind, _, rest = text.partition(":")
    try:
        if kind != "elastic" or not rest:
            if rest:
                raise argparse.ArgumentTypeError(f"boundary: only an elastic rim takes values, got {text!r}")
            return Support(kind)
        fields = dict(_parse_param(part) for part in rest.split(":"))
        unknown = set(fields) - {"k", "kr"}
        if unknown:
            raise argparse.ArgumentTypeError(f"boundary: an elastic rim takes k= and kr=, got {sorted(unknown)}")
        return Support("elastic", parse_quantity(fields.get("k", "0"), "N/m^2", "k"),
                       parse_quantity(fields.get("kr", "0"), "N", "kr"))
    except (UnitError, ModelError) as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _fe_supports(text: str) -> dict:
    if "=" not in text.split(":")[0]:
        return {"rim": _fe_support(text)}
    return {name: _fe_support(kind) for name, kind in (_parse_param(part) for part in text.split(","))}


def _fe_patch(text: str):
    from modalctl.model.structures import PlatePatch

    (x0, x1, y0, y1), _ = _fe_lengths(text, 4, "patch")
    if not (x0 < x1 and y0 < y1):
        raise argparse.ArgumentTypeError(f"patch: expected X0 < X1 and Y0 < Y1, got {text!r}")
    return PlatePatch((x0, x1), (y0, y1))


def _fe_sensor(text: str) -> tuple[float, float]:
    (x, y), _ = _fe_lengths(text, 2, "sensor")
    return x, y


def _model(args) -> int:
    from modalctl.model.fe_plate import FEPlate
    from modalctl.model.structures import PlatePatch

    for name, items, most in (("hole", args.hole, FE_HOLES_MAX), ("patch", args.patch, FE_PATCHES_MAX),
                              ("sensor", args.sensor, FE_SENSORS_MAX)):
        if len(items) > most:
            raise ParamError(f"model fe: at most {most} --{name} options, got {len(items)}")
    outline = dataclasses.replace(args.outline, holes=tuple(args.hole))  # the holes checked against it
    patches = tuple(PlatePatch(p.xlim, p.ylim, f"patch{i + 1}") for i, p in enumerate(args.patch))
    plate = FEPlate(outline, args.thickness, args.material, args.boundary, patches, tuple(args.sensor))
    say = None if args.quiet or args.json else (
        lambda level: print(f"mesh of {level.size * 1e3:.2g} mm: {level.dofs} dofs, {level.seconds:.1f} s", flush=True))
    model, convergence = plate.modal_model(args.modes, band=args.band, spacing=args.spacing, damping=args.damping,
                                           tolerance=args.tolerance, meta={"name": Path(args.out).stem},
                                           progress=say)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    path = model.save(out)
    summary = {"model_file": str(path), "modes": model.n_modes, "frequencies_hz": model.frequencies.tolist(),
               "convergence": convergence.to_dict(), "grid": list(model.grid.shape or (model.grid.n,))}
    if not args.no_plots:
        from .report import plot_fe_plate

        summary["pictures"] = plot_fe_plate(model, convergence, path.with_suffix(""))
    if args.json:
        print(json.dumps(summary))
        return 0
    print(f"{model.n_modes} modes from {model.frequencies[0]:.1f} to {model.frequencies[-1]:.1f} Hz, converged to "
          f"{convergence.frequency_error.max():.3%} (shapes: subspace MAC >= {convergence.shape_mac.min():.4f}) on "
          f"{convergence.levels[-1].dofs} dofs")
    print(f"model: {path}" + (f"; pictures: {', '.join(summary['pictures'])}" if "pictures" in summary else ""))
    return 0


def _scenes(args) -> int:
    if args.json:
        print(json.dumps({name: s.summary for name, s in SCENES.items()}, indent=2))
    else:
        for name, s in SCENES.items():
            print(f"{name:18s} {s.summary}")
    return 0


def _plugins(args) -> int:
    plugins, shapes = plugin_table(), shape_generators()
    if args.json:
        shape_rows = {n: {"summary": g.summary, "params": [{"name": p.name, "unit": p.unit, "default": p.default,
                                                             "required": p.required, "doc": p.doc}
                                                            for p in g.params]} for n, g in shapes.items()}
        print(json.dumps({"plugins": plugins, "shapes": shape_rows}, indent=2, default=str))
        return 0
    print("plugins:")
    for row in plugins:
        print(f"  {row['name']:28s} {row['distribution']:20s} hooks: {', '.join(row['hooks']) or '-'}")
    print("shapes:")
    for name, g in shapes.items():
        params = ", ".join(f"{p.name}[{p.unit}]" + ("*" if p.required else "") for p in g.params)
        print(f"  {name:10s} {g.summary}\n  {'':10s} params: {params}   (* required)")
    return 0


def _model_and_shape(args):
    model = load_scene(args.scene, args.points) if args.scene is not None else ModalModel.load(args.model)
    generator = get_shape(args.shape)
    return model, generator.generate(model.grid, **parse_params(generator, dict(args.param)))


def _decompose(args) -> int:
    model, shape = _model_and_shape(args)
    result = decompose(model, shape, args.modes, tau_min=args.tau_target, nrmse_max=args.nrmse_target,
                       orthogonalize=args.orthogonalize)
    summary = result.to_dict()
    if args.plot:
        from .report import plot_decomposition

        summary["plot"] = str(plot_decomposition(result, args.plot))
    if args.save_model:
        summary["model_file"] = str(result.model.save(args.save_model))
    if args.json:
        print(json.dumps(summary))
        return 0
    print(f"scene {summary['scene']}, shape {args.shape}: {summary['rule']}")
    print(f"{'mode':>5s} {'f (Hz)':>10s} {'coefficient (m/s sqrt(kg))':>28s}")
    for label, f in zip(summary["modes_used"], summary["frequencies_hz"]):
        print(f"{label:5d} {f:10.1f} {summary['coefficients'][str(label)]:28.4e}")
    print(f"tau {summary['tau']:.4f}  tau_norm {summary['tau_norm']:.4f}  NRMSE {summary['nrmse']:.4f}  "
          f"focus contrast {summary['focus_contrast']:.2f}")
    print("error left: " + summary["error_left"])
    if summary["rigid_body_energy"] > 1e-6:
        print(f"rigid-body modes carry {100 * summary['rigid_body_energy']:.2f}% of the field's energy: "
              "no resonant drive can produce that part")
    if args.plot:
        print(f"picture: {summary['plot']}")
    return 0


def _out_dir(text: str) -> str:
    """``--out``: a directory to write into (made if absent); not empty, not an existing file."""
    if not text.strip():
        raise argparse.ArgumentTypeError("out: give a directory (an empty name would write into the working one)")
    if Path(text).exists() and not Path(text).is_dir():
        raise argparse.ArgumentTypeError(f"out: {text!r} is a file, not a directory")
    return text


def _margin(text: str) -> float | None:
    """``--margin``: a share of the focus peak in (0, 1], or ``none``."""
    if text.strip().lower() == "none":
        return None
    return quantity_type("1", "margin", low=0, high=1)(text)


def _margin_words(margin: float | None) -> str:
    return "none" if margin is None else f"{margin:g}"


def _run_options(args, out: Path) -> RunOptions:
    """The typed options of ``modalctl run``."""
    if args.learn and args.loop == "open":
        raise ParamError("--learn needs a closed loop (--loop closed or board)")
    get_planner(args.planner)  # an unknown planner is bad input, refused before the device opens
    plan = PlanOptions(planner=args.planner, modes=args.modes, tau_min=args.tau_target or PLAN.tau_min,
                       margin=args.margin, margin_on=args.margin_on, voltage_limit=args.voltage_limit,
                       slew_limit=args.slew_limit, robust_drift=args.robust_drift, kappa=args.kappa,
                       brake=not args.no_brake, after=args.after, sample_rate=args.sample_rate)
    loop = None if args.loop == "open" else LoopOptions(
        control_rate=args.control_rate, controller=args.controller, on_board=args.loop == "board",
        authority=args.authority, latency=args.latency, slew_limit=args.slew_limit, watchdog=args.watchdog,
        touch_at=args.touch_at)
    return RunOptions(args.focus_time, plan, loop, args.learn, out / "log" if loop else None, not args.quiet)


def _open_device(args, model=None, shape=None):
    """The device at ``--transport`` with its transport's own options; another transport's are refused."""
    from urllib.parse import urlsplit

    from modalctl.io.device import open_device

    scheme = urlsplit(args.transport).scheme
    misplaced = args.transports.misplaced(args, scheme)
    if misplaced:
        raise ParamError(f"{', '.join(misplaced)}: not an option of {scheme}:// (--transport {args.transport})")
    return open_device(args.transport, DeviceContext(model, shape, args.transports.of(args, scheme)))


def _run(args) -> int:
    import warnings

    from modalctl.plan.dispatch import DecouplingWarning

    from .run import run

    warnings.simplefilter("ignore", DecouplingWarning)  # printed below from the metrics
    out = Path(args.out)
    options = _run_options(args, out)
    model, shape = _model_and_shape(args)
    with _open_device(args, model, shape) as device:  # its options checked before the folder is made
        claim(out, "run", _identity(args), args.force, _identity_defaults("run"))
        try:
            shot = run(model, shape, device, options)
        except PlanError as refused:  # a result: why, on disk beside where the report would be
            _write_json(out / "refusal.json", {"refused": str(refused), "needed": refused.needed,
                                               "limit": refused.limit, "certificate": refused.certificate,
                                               "planner": options.plan.planner})
            raise
        except DeviceError as fault:
            _halted(out, device, fault)
            raise
        return _report(args, model, shot, device, out)


def _halted(out: Path, device, fault: Exception) -> None:
    """After a device fault: every output commanded to zero (best effort), and what happened in
    ``out/metrics.json`` beside the loop's log, so the run's folder says why it has no field."""
    could_not = device.halt()
    log = out / "log.json"
    metrics = {"fault": str(fault), "exit_code": DEVICE, "device": device.url, "device_info": device.info,
               "outputs": "commanded to zero" if could_not is None else f"not confirmed at zero: {could_not}",
               "log": str(log) if log.exists() else None, "out": str(out)}
    _write_json(out / "metrics.json", metrics)


def _identity(args) -> dict:
    """The options that make a run what it is (not how it is shown): a folder holding results of
    other options holds another run."""
    shown = {"quiet", "force", "json", "no_plots", "transports", "out", "command"}
    return {k: v for k, v in sorted(vars(args).items()) if k not in shown and not callable(v)}


def _identity_defaults(command: str) -> dict:
    """Every option of ``command`` at its default (the simulator's own included)."""
    parser = build_parser().commands[command]
    return {action.dest: parser.get_default(action.dest) for action in parser._actions
            if action.dest != argparse.SUPPRESS}


def _write_json(path: Path, value) -> None:
    """``value`` as JSON at ``path``, atomically (see :mod:`modalctl.outdir`)."""
    with atomic(path) as temporary:
        temporary.write_text(json.dumps(value, indent=2, default=_jsonable))


def _report(args, model, shot, device, out) -> int:
    """metrics.json, fields.npz and the pictures of a run; the summary on stdout."""
    import numpy as np

    metrics = {**shot.to_dict(), "scene": model.meta.get("name", args.model), "shape": args.shape,
               "params": dict(args.param), "truth": device.info.get("truth", device.url), "out": str(out)}
    coeffs = shot.coefficients()
    # the field scan is stored in float32 (7 digits, far below any measurement noise) to keep runs small
    with atomic(out / "fields.npz") as temporary:
        np.savez_compressed(temporary, times=shot.times, field=shot.field.astype(np.float32),
                            focus_field=shot.focus_field,
                            target=shot.decomposition.shape.values, target_mask=shot.decomposition.shape.target_mask,
                            grid=model.grid.points,
                            sample_times=shot.capture.times, voltages=shot.capture.voltages,
                            sensors=shot.capture.sensors, focus_point_velocity=shot.focus_velocity,
                            labels=np.asarray(model.labels), **{f"coefficients_{k}": v for k, v in coeffs.items()})
    if not args.no_plots:
        from .report import write_run_report

        metrics["pictures"] = write_run_report(shot, out)
        record(out, [Path(picture).name for picture in metrics["pictures"].values()])
    _write_json(out / "metrics.json", metrics)
    fault = metrics.get("loop", {}).get("fault")
    if fault:  # the supervisor stopped the shot: the report is written, the run did not succeed
        print(f"modalctl run: the supervisor stopped the shot: {fault}; outputs ramped to zero, "
              f"log in {out}/log.json + log.bin", file=sys.stderr)
    if args.json:
        print(json.dumps(metrics, default=_jsonable))
        return DEVICE if fault else 0
    m = metrics
    print(f"{m['scene']}, {args.shape} {' '.join(f'{k}={v}' for k, v in args.param)}, T_F {args.focus_time * 1e3:g} ms, "
          f"truth: {m['truth']}")
    print(f"modes {m['modes_used']}")
    print(f"tau {m['tau']:.4f} (model {m['tau_model']:.4f})  tau_norm {m['tau_norm']:.4f}  NRMSE {m['nrmse']:.4f}")
    held = m["margin_planned"]
    if held is not None and held != m["margin_criterion"]:
        band = (m["program"] or {}).get("robust_drift")
        print(f"the closed loop's plan holds {held:g} (headroom for its feedback)"
              + (f" over +-{100 * band:g}% of resonance drift" if band else ""))
    planned = (f"planned {m['whole_model_margin_ratio']:.3f} on every sample of the whole model"
               if m["planner"] == "convex" else f"planned {m['predicted_margin_ratio']:.3f} on the kept modes, "
               f"{m['whole_model_margin_ratio']:.3f} predicted on the whole model")
    print(f"margin ratio {m['margin_ratio']:.3f} measured ({'met' if m['margin_ok'] else 'NOT met'}: criterion "
          f"{m['margin_criterion']:g}); {planned}; peak voltage {m['peak_voltage']:.1f} V")
    print(f"plan {m['plan_seconds']:.2f} s ({m['planner']} planner), device {m['sim_seconds']:.2f} s")
    if "loop" in m:
        lp = m["loop"]
        where = "on the board" if lp.get("on_board") else f"{1e6 * (lp['step_seconds_median'] or 0):.0f} us per update"
        ended = (f"stopped by a fault ({lp['fault']})" if lp["fault"] else
                 f"ran {lp['periods']} periods and ended {lp['state']}")  # inactive: the lifecycle's rest state
        print(f"closed loop at {lp['control_rate_hz'] / 1e3:g} kHz: {ended}, "
              + (f"{lp['periods']} periods, " if lp["fault"] else "") + f"{where}, crossovers "
              f"{min(lp['crossover_hz']):.0f}-{max(lp['crossover_hz']):.0f} Hz; log: {out}/log.json + log.bin")
        print(f"the shot took {lp['real_time_factor']:.2f}x its played time (set-up, loop, log, records; "
              f"design {lp['design_seconds']:.2f} s and the field's scan {lp['scan_seconds']:.2f} s besides)")
    if shot.learning is not None:
        ls = shot.learning
        how = (f"fit {ls.update_seconds:.1f} s, misfit {100 * ls.misfit:.1f}%" if ls.source == "record"
               else "a pole tracker during the shot")
        print(f"learning shot: tau {ls.tau:.4f}, margin ratio {ls.margin_ratio:.3f}; its {ls.source} moved the "
              f"resonances by {100 * ls.common_shift:+.2f}% in common ({100 * min(ls.relative_shift):+.2f}% "
              f"to {100 * max(ls.relative_shift):+.2f}%; {how}); the numbers above are the shot planned again "
              f"on the updated model")
    for w in m["decoupling_warnings"]:
        print("warning: " + w)
    print(f"report: {out}/ (metrics.json, fields.npz" + (", pictures)" if "pictures" in m else ")"))
    return DEVICE if fault else 0


# swept parameter -> (Case field, unit of its values)
SWEPT = {"drift": ("drift", "1"), "damping-error": ("damping_error", "1"), "finger": ("finger", "N s/m"),
         "latency": ("latency", None), "snr": ("snr_db", None), "focus-time": ("focus_time", "s"),
         "seed": ("seed", None)}


def _swept_values(name: str, text: str) -> tuple[str, list]:
    if name not in SWEPT:
        raise ParamError(f"cannot sweep {name!r}; choose from {', '.join(SWEPT)}")
    field, unit = SWEPT[name]
    values = []
    for item in text.split(","):
        if unit is not None:
            values.append(parse_quantity(item, unit, name))
        else:
            try:
                values.append(int(item) if field in ("latency", "seed") else float(item))
            except ValueError:
                raise ParamError(f"{name}: expected numbers separated by commas, got {item!r}") from None
    if field in ("latency", "seed", "finger") and min(values) < 0:
        raise ParamError(f"{name}: values must be zero or more, got {min(values):g}")
    if field == "focus_time" and min(values) <= 0:
        raise ParamError(f"{name}: values must be positive, got {min(values):g} s")
    return field, values


def _sweep(args) -> int:
    import itertools
    from dataclasses import replace

    from modalctl.experiments.executor import executor_for
    from modalctl.experiments.sweep import METHODS, Case, run_case

    if not 1 <= len(args.vary) <= 2:
        raise ParamError("give one or two --vary NAME=V1,V2,... (e.g. --vary drift=0,1%,2%)")
    axes = [_swept_values(name, text) for name, text in args.vary]
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    unknown = set(methods) - set(METHODS)
    if unknown:
        raise ParamError(f"unknown method(s) {', '.join(sorted(unknown))}; choose from {', '.join(METHODS)}")
    get_shape(args.shape)  # a clear error before any work
    get_planner(args.planner)
    if args.points is None and args.scene in SCENES and isinstance(SCENES[args.scene].default_points, int):
        args.points = 211  # a beam: a fifth of the scenes' grids draws their modes and runs five times faster
    load_scene(args.scene, args.points)
    params = tuple(args.param) or (("width", "18mm"), ("center", "24mm"))
    base = Case(args.scene, args.shape, params, args.focus_time, "open", args.drift, args.damping_error,
                snr_db=args.snr, planner=args.planner, margin=args.margin, points=args.points,
                control_rate=args.control_rate,
                sample_rate=args.sample_rate, controller=args.controller, seed=args.seed)
    get_controller(args.controller)
    cases = [replace(base, method=m, **dict(zip([f for f, _ in axes], values)))
             for m in methods for values in itertools.product(*[v for _, v in axes])]
    out = claim(Path(args.out), "sweep", _identity(args), args.force, _identity_defaults("sweep"))
    executor = executor_for(args.scheduler, args.workers)
    rows = executor.map(run_case, cases, progress=not args.quiet)
    summary = {"axes": {f: v for f, v in axes}, "methods": methods, "rows": rows,
               "executor": type(executor).__name__}
    _write_json(out / "sweep.json", summary)
    from .report import plot_sweep_maps, sweep_table

    with atomic(out / "sweep.md") as temporary:
        temporary.write_text(sweep_table(rows, [f for f, _ in axes]))
    record(out, ["maps.png"])
    summary["pictures"] = {"maps": str(plot_sweep_maps(rows, [f for f, _ in axes], methods, out / "maps.png"))}
    if args.json:
        print(json.dumps(summary, default=_jsonable))
    else:
        print((out / "sweep.md").read_text())
        print(f"report: {out}/ (sweep.json, sweep.md, maps.png)")
    return 0


def _emulate(args) -> int:
    import time

    from modalctl.hil.scenario import Perturbation
    from modalctl.hil.serial_board import SerialBoardEmulator

    model = load_scene(args.scene, args.points)
    misplaced = args.transports.misplaced(args, "sim")
    if misplaced:
        raise ParamError(f"{', '.join(misplaced)}: not an option of the simulated board")
    if args.truth:
        raise ParamError("emulate: the structure is --scene (--truth is for modalctl run)")
    perturbation = Perturbation.from_options(args.transports.of(args, "sim"), model)
    with SerialBoardEmulator(model, perturbation, args.latency) as board:
        print(f"board emulator for {args.scene} ({perturbation.describe()}) on {board.path}", flush=True)
        print(f"use: modalctl run ... --transport serial://{board.path}   (Ctrl-C to stop)", flush=True)
        start = time.monotonic()
        try:
            while args.seconds is None or time.monotonic() - start < args.seconds:
                time.sleep(0.1)
        except KeyboardInterrupt:
            pass
    return 0


def _density(args, meta: dict, dim: int) -> float:
    """Mass per length (beam, kg/m) or per area (plate, kg/m^2) for a survey on ``dim``-D points:
    the option, or the scene's; the other option is refused."""
    wanted, other = ("mass_per_length", "mass_per_area") if dim == 1 else ("mass_per_area", "mass_per_length")
    flag = "--" + wanted.replace("_", "-")
    if getattr(args, other) is not None:
        raise ParamError(f"identify: the points are {'on a line' if dim == 1 else 'on a plate'}: give {flag}, "
                         f"not --{other.replace('_', '-')}")
    if getattr(args, wanted) is not None:
        return getattr(args, wanted)
    try:
        per_area = meta["density_kg_m3"] * meta["thickness_m"]
        return per_area if dim == 2 else per_area * meta["width_m"]
    except KeyError:
        unit = "kg/m" if dim == 1 else "kg/m^2"
        raise ParamError(f"identify: give {flag} ({unit}): it scales the shapes and gains") from None


def _identify(args) -> int:
    import numpy as np

    from modalctl.identify.frf import Sweep, read_uff58
    from modalctl.identify.survey import beam_wavelength, identify_device, identify_frf, scan_subset

    scene = load_scene(args.scene) if args.scene else None
    if args.frf is None and args.transport.startswith("sim") and scene is None:
        raise ModelError("identify: the simulator needs --scene (the structure to simulate)")
    meta = scene.meta if scene is not None else {}
    if args.frf:
        frf = read_uff58(args.frf)
        survey = identify_frf(frf, _density(args, meta, frf.points.shape[1]), args.method, not args.no_orthogonalize)
        points = np.arange(survey.model.grid.n)
    else:
        sweep = Sweep.design(args.f_low, args.f_high, args.resolution, args.amplitude)
        options = SurveyOptions(method=args.method, primary=args.primary, averages=args.averages,
                                orthogonalize=not args.no_orthogonalize)
        with _open_device(args, scene) as device:
            caps = device.configure(sweep.sample_rate)
            scan = np.asarray(caps.scan_points, float).reshape(len(caps.scan_points), -1)
            density = _density(args, meta, scan.shape[1])
            points = scan_subset(scan, args.step)
            if points.size < SCAN_POINTS_MIN ** scan.shape[1]:  # said now, not after the whole survey
                raise ParamError(f"identify: --step {args.step * 1e3:g} mm leaves {points.size} scan point(s) on "
                                 f"{' x '.join(f'{e * 1e3:.0f}' for e in np.ptp(scan, axis=0))} mm; at least "
                                 f"{SCAN_POINTS_MIN} per direction draw a mode shape")
            survey = identify_device(device, sweep, points, density, options, beam_wavelength(meta, args.f_high),
                                     progress=not args.quiet)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    path = survey.model.save(out)
    off = lambda c: float(np.max(np.abs(c - np.eye(len(c)))))  # noqa: E731
    summary = {"model_file": str(path), "modes": survey.model.n_modes, "method": args.method,
               "frequencies_hz": survey.model.frequencies.tolist(), "damping": survey.model.damping.tolist(),
               "poles": survey.poles.summary(), "notes": survey.notes, "seconds": survey.seconds,
               "points": int(points.size), "crosstalk_max_before": off(survey.crosstalk_before),
               "crosstalk_max_after": off(survey.crosstalk_after)}
    if not args.no_plots:
        from .report import plot_identification

        summary["pictures"] = plot_identification(survey, path.with_suffix(""))
    if args.json:
        print(json.dumps(summary))
        return 0
    print(f"identified {summary['modes']} modes on {points.size} points with {args.method} "
          f"({survey.seconds['frf'] + survey.seconds['modal']:.2f} s compute)")
    print(f"{'mode':>5s} {'f (Hz)':>10s} {'zeta':>9s}")
    for i, (f, z) in enumerate(zip(survey.model.frequencies, survey.model.damping)):
        print(f"{i + 1:5d} {f:10.1f} {z:9.5f}")
    for note in survey.notes:
        print("note: " + note)
    print(f"cross-talk: max {summary['crosstalk_max_before']:.3f} before Gram-Schmidt, "
          f"{summary['crosstalk_max_after']:.1e} after")
    print(f"model: {path}" + (f"; pictures: {', '.join(summary['pictures'])}" if "pictures" in summary else ""))
    return 0


def _jsonable(value):
    import numpy as np

    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)


def _say_warning(message, category, filename, lineno, file=None, line=None) -> str:
    """Warnings on the command line as one plain line (not the source line that raised them)."""
    return f"modalctl: warning: {message}\n"


def _negatives_attached(argv: list[str]) -> list[str]:
    """``--drift -1%`` as ``--drift=-1%``: argparse takes a value with a unit after a minus sign
    for an unknown option (it only knows bare negative numbers)."""
    out: list[str] = []
    for token in argv:
        if out and NEGATIVE.match(token) and out[-1].startswith("--") and "=" not in out[-1]:
            out[-1] = f"{out[-1]}={token}"
        else:
            out.append(token)
    return out


def main(argv=None) -> int:
    import warnings

    warnings.formatwarning = _say_warning
    argv = _negatives_attached(list(sys.argv[1:] if argv is None else argv))
    args = _parse(argv)
    if args.command in REAL_TIME:  # shots reuse their memory instead of faulting on fresh pages each time
        keep_memory()
    handlers = {"scenes": _scenes, "plugins": _plugins, "decompose": _decompose, "run": _run,
                "identify": _identify, "sweep": _sweep, "emulate": _emulate, "model": _model}
    as_json = getattr(args, "json", False)
    try:
        return handlers[args.command](args)
    except DeviceError as exc:
        return _refuse(args.command, DEVICE, f"device error: {exc}", as_json)
    except PlanError as exc:
        code = _refuse(args.command, UNREACHABLE, f"no plan: {exc}", as_json, certificate=exc.certificate)
        if exc.certificate:
            print(f"certificate: {json.dumps(exc.certificate, default=_jsonable)}", file=sys.stderr)
        return code
    except ReductionError as exc:
        return _refuse(args.command, UNREACHABLE, str(exc), as_json)
    except (UnknownScene, PluginError, ParamError, UnitError, ModelError, ValueError) as exc:
        return _refuse(args.command, BAD_INPUT, f"error: {exc}", as_json)


def _parse(argv: list[str]) -> argparse.Namespace:
    """The command line, parsed; with ``--json``, a refusal also goes to stdout as a JSON object."""
    if "--json" not in argv:
        return build_parser().parse_args(argv)
    said = io.StringIO()
    try:
        with contextlib.redirect_stderr(said):
            return build_parser().parse_args(argv)
    except SystemExit as exc:
        sys.stderr.write(said.getvalue())
        if exc.code:  # 0: --help
            lines = [line for line in said.getvalue().splitlines() if line.strip()]
            _refuse(argv[0] if argv else "", BAD_INPUT, lines[-1] if lines else "bad input", True, stderr=False)
        raise


def _refuse(command: str, code: int, message: str, as_json: bool, certificate=None, stderr: bool = True) -> int:
    """Say why a command ends with ``code``: on stderr, and with ``--json`` as ``{"error", "code"}``
    (and the certificate of a refused plan) on stdout. Returns ``code``."""
    if stderr:
        print(f"modalctl {command}: {message}", file=sys.stderr)
    if as_json:
        body = {"error": message, "code": code, "command": command}
        if certificate:
            body["certificate"] = certificate
        print(json.dumps(body, default=_jsonable))
    return code


if __name__ == "__main__":
    sys.exit(main())
