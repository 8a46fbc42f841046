"""The ``modalctl`` command: ``scenes``, ``plugins``, ``decompose``.

Exit codes: 0 success, 1 a target that cannot be met, 2 bad input (unknown scene, shape or
parameter, bad units, unreadable file).
"""

from __future__ import annotations

import argparse
import json
import sys

from .decompose import decompose
from .model import ModalModel, ModelError
from .plugin import PluginError, get_shape, plugin_table, shape_generators
from .reduction import ReductionError
from .scenes import SCENES, UnknownScene, load_scene
from .shape import ParamError, parse_params
from .units import UnitError

BAD_INPUT, UNREACHABLE = 2, 1


def _parse_param(text: str) -> tuple[str, str]:
    if "=" not in text:
        raise argparse.ArgumentTypeError(f"expected name=value, got {text!r}")
    name, value = text.split("=", 1)
    return name.strip(), value.strip()


def _modes(text: str):
    if text in ("auto", "all"):
        return text
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected auto, all or a number of modes, got {text!r}") from None


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="modalctl", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("scenes", help="list the named scenes")
    p.add_argument("--json", action="store_true")

    p = sub.add_parser("plugins", help="list installed plugins and shape generators")
    p.add_argument("--json", action="store_true")

    p = sub.add_parser("decompose", help="project a target field on a scene's modes and reduce")
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--scene", help="scene name (see 'modalctl scenes')")
    source.add_argument("--model", help="modal model file (.npz written by modalctl)")
    p.add_argument("--shape", required=True, help="shape generator (see 'modalctl plugins')")
    p.add_argument("--param", action="append", default=[], type=_parse_param, metavar="NAME=VALUE",
                   help="shape parameter with units, e.g. width=18mm (repeatable)")
    p.add_argument("--modes", type=_modes, default="auto",
                   help="auto (smallest set meeting the target), all, or N (the N lowest modes)")
    p.add_argument("--tau-target", type=float, help="auto: least tau for the kept modes (default 0.98)")
    p.add_argument("--nrmse-target", type=float, help="auto: largest NRMSE for the kept modes")
    p.add_argument("--orthogonalize", action="store_true", help="Gram-Schmidt the mode shapes first")
    p.add_argument("--points", type=int, help="grid points of a beam scene (default: the scene's)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--plot", metavar="FILE.png", help="draw the field and the modal bars")
    p.add_argument("--save-model", metavar="FILE.npz", help="also write the model used")
    return parser


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


def _decompose(args) -> int:
    if args.scene:
        model = load_scene(args.scene, args.points)
    else:
        model = ModalModel.load(args.model)
    generator = get_shape(args.shape)
    shape = generator.generate(model.grid, **parse_params(generator, dict(args.param)))
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


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    handlers = {"scenes": _scenes, "plugins": _plugins, "decompose": _decompose}
    try:
        return handlers[args.command](args)
    except ReductionError as exc:
        print(f"modalctl {args.command}: {exc}", file=sys.stderr)
        return UNREACHABLE
    except (UnknownScene, PluginError, ParamError, UnitError, ModelError, ValueError) as exc:
        print(f"modalctl {args.command}: error: {exc}", file=sys.stderr)
        return BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
