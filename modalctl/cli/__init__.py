"""The ``modalctl`` command: ``scenes``, ``plugins``, ``decompose``, ``identify``, ``run``, ``sweep``, ``emulate``,
``model fe``.

Exit codes: 0 success, 1 a target that cannot be met (no mode set or no plan meets it: the
message says by how much), 2 bad input (unknown scene, shape or parameter, bad units,
unreadable file: an :class:`~modalctl.errors.InputError`), 3 a device error or a closed-loop shot
stopped by the supervisor, 4 an internal error (anything else a command raises: a bug, said in one
line, its traceback in a file; docs/errors.md).

One module per command (``modalctl/cli/run.py`` is ``modalctl run``), each with ``add_parser(sub)``
and ``run(args) -> int``; what they share is :mod:`modalctl.cli.common`. Commands plugins add
(hook ``modalctl_commands``: ``emulate`` is the HIL's) join them. A command's options are declared
only when it is chosen, and what it needs to run is imported inside its ``run``: ``modalctl
--help`` loads neither numpy nor a plugin's numerical modules.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import re
import sys

from modalctl.plugin.command import plugin_commands

from . import decompose, identify, model, plugins, run, scenes, sweep
from .common import BAD_INPUT, DEVICE, UNREACHABLE, internal_error, jsonable, refuse

__all__ = ["main", "build_parser", "command_parser"]

BUILT_IN = (scenes, plugins, decompose, run, sweep, identify, model)  # in the order --help lists them
OWN = {module.NAME for module in BUILT_IN}  # the commands whose plain ValueError is a bug (a plugin's may be bad input)
NEGATIVE = re.compile(r"^-\.?\d")  # a value, not an option: -1%, -30mm, -.5


class Commands(argparse._SubParsersAction):
    """The sub-commands, each with its handler; a command's options are added when it is chosen
    (or by :meth:`fill`), so that listing the commands imports nothing a command needs."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.handlers: dict = {}  # name -> run(args) -> int
        self._unfilled: dict = {}  # name -> add_arguments(parser), until called

    def add_command(self, name: str, help: str, add_arguments, handler, description: str | None = None):
        """A sub-parser ``name`` whose options ``add_arguments(parser)`` declares, run by ``handler``."""
        parser = self.add_parser(name, help=help, description=description)
        self.handlers[name] = handler
        self._unfilled[name] = add_arguments
        return parser

    def fill(self, name: str) -> argparse.ArgumentParser:
        """The parser of command ``name`` with its options."""
        add_arguments = self._unfilled.pop(name, None)
        if add_arguments is not None:
            add_arguments(self.choices[name])
        return self.choices[name]

    def __call__(self, parser, namespace, values, option_string=None):
        self.fill(values[0])
        super().__call__(parser, namespace, values, option_string)


def build_parser(lazy: bool = False) -> argparse.ArgumentParser:
    """The command line's parser: every command's options, or with ``lazy`` only the chosen one's
    (added as it is parsed). ``parser.commands``: each command's parser, by name;
    ``parser.subcommands``: the :class:`Commands` action (``fill(name)``, ``handlers``)."""
    parser = argparse.ArgumentParser(prog="modalctl", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, action=Commands)
    for module in BUILT_IN:
        module.add_parser(sub)
    for command in plugin_commands().values():
        if command.name in sub.choices:
            from modalctl.plugin.manager import PluginError

            raise PluginError(f"a plugin's command {command.name!r} is a command of modalctl's own")
        sub.add_command(command.name, command.help, command.add_arguments, command.run, command.description)
    parser.commands, parser.subcommands = sub.choices, sub
    if not lazy:
        for name in sub.choices:
            sub.fill(name)
    return parser


def command_parser(name: str) -> argparse.ArgumentParser:
    """The parser of command ``name`` alone, with its options (their defaults: a run's identity)."""
    return build_parser(lazy=True).subcommands.fill(name)


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
    parser = build_parser(lazy=True)
    try:
        args = _parse(parser, argv)
    except Exception as exc:  # noqa: BLE001 (an option's type that raised what argparse does not take: a bug)
        return internal_error(argv[0] if argv else "", exc, "--json" in argv)
    return _dispatch(parser.subcommands.handlers[args.command], args, own=args.command in OWN)


def _dispatch(handler, args, own: bool = True) -> int:
    """``handler(args)``, its refusals turned into their exit codes and messages; anything else it
    raises is a bug, exit 4 in one line with its traceback in a file (:func:`.common.internal_error`).
    A plugin's command (not ``own``) may refuse bad input with a plain ValueError (docs/plugins.md)."""
    from modalctl.errors import InputError
    from modalctl.io.device import DeviceError
    from modalctl.model.scenes import UnknownScene
    from modalctl.outdir import CLAIMED
    from modalctl.plan.planner import PlanError
    from modalctl.plan.reduction import ReductionError
    from modalctl.plugin.manager import PluginError

    as_json, claims = getattr(args, "json", False), len(CLAIMED)
    try:
        return handler(args)
    except DeviceError as exc:
        return refuse(args.command, DEVICE, f"device error: {exc}", as_json)
    except PlanError as exc:
        code = refuse(args.command, UNREACHABLE, f"no plan: {exc}", as_json, certificate=exc.certificate)
        if exc.certificate:
            print(f"certificate: {json.dumps(exc.certificate, default=jsonable)}", file=sys.stderr)
        return code
    except ReductionError as exc:
        return refuse(args.command, UNREACHABLE, str(exc), as_json)
    except (UnknownScene, PluginError, InputError) as exc:  # ModelError, ParamError, UnitError, OutDirError...
        return refuse(args.command, BAD_INPUT, f"error: {exc}", as_json)
    except ValueError as exc:  # a check of the core's own contracts, or numpy's: a bug (a plugin's command: its input)
        if own:
            return internal_error(args.command, exc, as_json, _claimed_since(claims))
        return refuse(args.command, BAD_INPUT, f"error: {exc}", as_json)
    except OSError as exc:  # a file the system refused (the readers and outdir.atomic name theirs already)
        return refuse(args.command, BAD_INPUT, f"error: {exc}", as_json)
    except MemoryError as exc:  # an allocation no estimate refused first (numpy's "Unable to allocate ...")
        return refuse(args.command, BAD_INPUT, f"error: more memory than there is ({exc or 'out of memory'}): ask for "
                      "less (a smaller band, grid or tolerance, a shorter shot)", as_json)
    except KeyboardInterrupt as exc:  # Ctrl-C, or a signal common.interruptible turned into it: no traceback
        return refuse(args.command, getattr(exc, "code", 128 + 2), str(exc) or "interrupted by SIGINT", as_json)
    except Exception as exc:  # noqa: BLE001 (what no check raises: a bug, said in one line, its traceback on disk)
        return internal_error(args.command, exc, as_json, _claimed_since(claims),
                              "modalctl" if own else f"the plugin that adds {args.command!r}, or in modalctl")


def _claimed_since(claims: int):
    """The folder the command claimed for its results (the last of :data:`modalctl.outdir.CLAIMED`
    after the first ``claims``), or None."""
    from modalctl.outdir import CLAIMED

    return CLAIMED[-1] if len(CLAIMED) > claims else None


def _parse(parser: argparse.ArgumentParser, argv: list[str]) -> argparse.Namespace:
    """The command line, parsed; with ``--json``, a refusal also goes to stdout as a JSON object."""
    if "--json" not in argv:
        return parser.parse_args(argv)
    said = io.StringIO()
    try:
        with contextlib.redirect_stderr(said):
            return parser.parse_args(argv)
    except SystemExit as exc:
        sys.stderr.write(said.getvalue())
        if exc.code:  # 0: --help
            lines = [line for line in said.getvalue().splitlines() if line.strip()]
            refuse(argv[0] if argv else "", BAD_INPUT, lines[-1] if lines else "bad input", True, stderr=False)
        raise


if __name__ == "__main__":
    sys.exit(main())
