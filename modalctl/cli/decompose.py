"""``modalctl decompose``: a target field projected on a scene's (or a model file's) modes, and the
set of modes kept."""

from __future__ import annotations

import json

from modalctl.units import number_type

from .common import add_target, model_and_shape, out_file, picture_file

NAME, HELP = "decompose", "project a target field on a scene's modes and reduce"


def add_parser(sub):
    return sub.add_command(NAME, HELP, add_arguments, run)


def add_arguments(p) -> None:
    add_target(p)
    p.add_argument("--nrmse-target", type=number_type(float, "nrmse-target", low=0),
                   help="auto: largest NRMSE for the kept modes")
    p.add_argument("--orthogonalize", action="store_true", help="Gram-Schmidt the mode shapes first")
    p.add_argument("--plot", metavar="FILE.png", type=picture_file, help="draw the field and the modal bars")
    p.add_argument("--save-model", metavar="FILE.npz", type=out_file, help="also write the model used")


def run(args) -> int:
    from modalctl.plan.decompose import decompose

    model, shape = model_and_shape(args)
    result = decompose(model, shape, args.modes, tau_min=args.tau_target, nrmse_max=args.nrmse_target,
                       orthogonalize=args.orthogonalize)
    summary = result.to_dict()
    if args.plot:
        from modalctl.report import plot_decomposition

        summary["plot"] = str(plot_decomposition(result, args.plot))
    if args.save_model:
        summary["model_file"] = str(result.model.save(args.save_model))
    if args.json:
        print(json.dumps(summary))
        return 0
    _print(args, summary)
    return 0


def _print(args, summary: dict) -> None:
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
