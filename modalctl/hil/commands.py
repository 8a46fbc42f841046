"""The HIL's command plugin: ``modalctl emulate``, the HIL board served on a serial device path.

The emulator is hardware-in-the-loop, so the HIL side contributes the command (hook
``modalctl_commands``, entry point group ``modalctl.commands``) and the command line imports no
simulator. Registered under the command group, this module is loaded before every parse: it
imports only the command contract at its top, and the simulator when the command is chosen.
"""

from __future__ import annotations

from modalctl.plugin.command import Command, grid_points
from modalctl.plugin.spec import hookimpl
from modalctl.units import number_type, quantity_type


class Emulate(Command):
    name = "emulate"
    help = "serve the HIL board on a serial device path (a pty) until interrupted"

    def add_arguments(self, parser):
        from modalctl.io.device import add_transport_options

        parser.add_argument("--scene", default="thesis-al-cc", help="the structure (thesis-al-cc)")
        parser.add_argument("--points", type=grid_points,
                            help="grid points: N for a beam, NxM for a plate (default: the scene's)")
        parser.set_defaults(transports=add_transport_options(parser))
        parser.add_argument("--latency", type=number_type(int, "latency", low=0, high=1000, low_open=False),
                            default=0, help="extra periods before a command is used")
        parser.add_argument("--for", dest="seconds", type=quantity_type("s", "for", low=0),
                            help="stop after this long (default: never)")

    def run(self, args) -> int:
        import time

        from .serial_board import SerialBoardEmulator
        from modalctl.loops.realtime import keep_memory

        keep_memory()  # the board plays shots: their memory reused instead of faulted in each time
        model, perturbation = _board_truth(args)
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


def _board_truth(args):
    """The emulated structure (``--scene``) and its truth from the simulator's own options; the
    other transports' options and ``--truth`` (another structure: ``modalctl run``'s) refused."""
    from .scenario import Perturbation
    from modalctl.model.scenes import load_scene
    from modalctl.model.shape import ParamError

    model = load_scene(args.scene, args.points)
    misplaced = args.transports.misplaced(args, "sim")
    if misplaced:
        raise ParamError(f"{', '.join(misplaced)}: not an option of the simulated board")
    options = args.transports.of(args, "sim")
    if options["truth"]:
        raise ParamError("emulate: the structure is --scene (--truth is for modalctl run)")
    return model, Perturbation.from_options(options, model)


@hookimpl
def modalctl_commands():
    return [Emulate()]
