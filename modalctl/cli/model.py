"""``modalctl model fe``: a plate's modal model by finite elements, from its geometry (outline,
holes, supports, material, patches, sensors), written as a model file every command takes.

The ``_fe_*`` functions read the geometry's options; the finite-element module is imported when
one of them is given, not to build the parser.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

from modalctl.units import UnitError, number_type, parse_quantity, quantity_type

from .common import out_file, parse_param

NAME, HELP = "model", "build a modal model from a structure's geometry"
FE_HOLES_MAX, FE_PATCHES_MAX, FE_SENSORS_MAX = 20, 32, 32


def add_parser(sub):
    return sub.add_command(NAME, HELP, add_arguments, run)


def add_arguments(model) -> None:
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
    p.add_argument("--out", required=True, type=out_file, help="model file to write (.npz); pictures beside it")
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
    from modalctl.model.modes import ModelError

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
    from modalctl.model.modes import ModelError

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
    from modalctl.model.modes import ModelError

    if text in MATERIALS:
        return MATERIALS[text]
    fields = dict(parse_param(part) for part in text.split(","))
    if set(fields) != {"E", "rho", "nu"}:
        raise argparse.ArgumentTypeError(f"material: one of {', '.join(MATERIALS)} or E=..,rho=..,nu=.., got {text!r}")
    try:
        return Material(parse_quantity(fields["E"], "Pa", "E"), parse_quantity(fields["rho"], "kg/m^3", "rho"),
                        parse_quantity(fields["nu"], "1", "nu"))
    except (UnitError, ModelError) as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _fe_support(text: str):
    from modalctl.model.fe_plate import Support
    from modalctl.model.modes import ModelError

    kind, _, rest = text.partition(":")
    try:
        if kind != "elastic" or not rest:
            if rest:
                raise argparse.ArgumentTypeError(f"boundary: only an elastic rim takes values, got {text!r}")
            return Support(kind)
        fields = dict(parse_param(part) for part in rest.split(":"))
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
    return {name: _fe_support(kind) for name, kind in (parse_param(part) for part in text.split(","))}


def _fe_patch(text: str):
    from modalctl.model.structures import PlatePatch

    (x0, x1, y0, y1), _ = _fe_lengths(text, 4, "patch")
    if not (x0 < x1 and y0 < y1):
        raise argparse.ArgumentTypeError(f"patch: expected X0 < X1 and Y0 < Y1, got {text!r}")
    return PlatePatch((x0, x1), (y0, y1))


def _fe_sensor(text: str) -> tuple[float, float]:
    (x, y), _ = _fe_lengths(text, 2, "sensor")
    return x, y


def _refuse_overlapping(patches) -> None:
    """Two patches on one place of the plate's back cannot both be bonded there (sharing an edge can)."""
    from modalctl.model.shape import ParamError

    for j, b in enumerate(patches):
        for i, a in enumerate(patches[:j]):
            if a.xlim[0] < b.xlim[1] and b.xlim[0] < a.xlim[1] and a.ylim[0] < b.ylim[1] and b.ylim[0] < a.ylim[1]:
                raise ParamError(f"model fe: --patch {i + 1} and --patch {j + 1} overlap: two patches cannot be "
                                 "bonded on one place of the plate's back")


def run(args) -> int:
    from modalctl.model.actuation import twin_modes
    from modalctl.model.fe_plate import FEPlate
    from modalctl.model.shape import ParamError
    from modalctl.model.structures import PlatePatch

    for name, items, most in (("hole", args.hole, FE_HOLES_MAX), ("patch", args.patch, FE_PATCHES_MAX),
                              ("sensor", args.sensor, FE_SENSORS_MAX)):
        if len(items) > most:
            raise ParamError(f"model fe: at most {most} --{name} options, got {len(items)}")
    _refuse_overlapping(args.patch)
    outline = dataclasses.replace(args.outline, holes=tuple(args.hole))  # the holes checked against it
    patches = tuple(PlatePatch(p.xlim, p.ylim, f"patch{i + 1}") for i, p in enumerate(args.patch))
    plate = FEPlate(outline, args.thickness, args.material, args.boundary, patches, tuple(args.sensor))
    say = None if args.quiet or args.json else (
        lambda level: print(f"mesh of {level.size * 1e3:.2g} mm: {level.dofs} dofs, {level.seconds:.1f} s", flush=True))
    model, convergence = plate.modal_model(args.modes, band=args.band, spacing=args.spacing, damping=args.damping,
                                           tolerance=args.tolerance, meta={"name": Path(args.out).stem},
                                           progress=say)
    if args.band is not None and model.frequencies[0] > args.band:  # the solve keeps one mode at least
        raise ParamError(f"model fe: no mode below --band {args.band:g} Hz: this plate's lowest is at "
                         f"{model.frequencies[0]:.0f} Hz; give a higher --band or --modes N")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    path = model.save(out)  # atomically: a file that was there stays whole if the disk refuses
    twins = twin_modes(model)
    summary = {"model_file": str(path), "modes": model.n_modes, "frequencies_hz": model.frequencies.tolist(),
               "convergence": convergence.to_dict(), "grid": list(model.grid.shape or (model.grid.n,)),
               "twin_modes": [t.to_dict(model) for t in twins]}
    if not args.no_plots:
        summary["pictures"] = _pictures(model, convergence, path.with_suffix(""))
    if args.json:
        print(json.dumps(summary))
        return 0
    print(f"{model.n_modes} modes from {model.frequencies[0]:.1f} to {model.frequencies[-1]:.1f} Hz, converged to "
          f"{convergence.frequency_error.max():.3%} (shapes: subspace MAC >= {convergence.shape_mac.min():.4f}) on "
          f"{convergence.levels[-1].dofs} dofs")
    if twins:
        print(_twins_note(model, twins))
    print(f"model: {path}" + (f"; pictures: {', '.join(summary['pictures'])}" if "pictures" in summary else ""))
    return 0


def _pictures(model, convergence, stem: Path) -> list[str]:
    """The plate's mode shapes drawn in a forked child (:mod:`modalctl.forked`) while this process draws its
    convergence: the tablet's two pictures in 1.7-2.1 s, not 3.1-3.8 s (the shapes also at zlib level 1)."""
    import functools

    from modalctl.forked import beside
    from modalctl.report import plot_fe_convergence, plot_fe_shapes

    shapes = beside(functools.partial(plot_fe_shapes, model, stem))
    try:
        drawn = plot_fe_convergence(model, convergence, stem)
    except BaseException:  # no child drawing on behind a failed command
        shapes.stop()
        raise
    return [shapes.result(), drawn]


def _twins_note(model, twins) -> str:
    """What a layout whose patches push close modes along one direction costs, in a sentence."""
    from modalctl.model.actuation import CLOSE, PARALLEL

    closest = twins[0]
    return (f"note: the patches push {len(twins)} pair(s) of close modes (within {CLOSE:.0%}) along one direction "
            f"(|cos| >= {PARALLEL}), the closest {closest.describe(model)}: a drive tells them apart only by "
            f"their beat, so a focus shorter than 1/{closest.spacing_hz:.3g} Hz = {1e3 / closest.spacing_hz:.3g} ms "
            f"that needs them in another proportion asks large, cancelling drives; patches placed off the "
            f"plate's symmetry axes avoid it")
