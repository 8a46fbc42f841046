"""What the commands share at the edge: exit codes, the argument types (``--param``, ``--points``,
``--modes``, ``--out``), the target's arguments, the refusal a command ends with, JSON output,
the identity of a run's folder, and the device at ``--transport``.

Light at import (argparse, json, the units parser): the parser is built without numpy, scipy or
the simulator; what a command needs to run is imported inside it.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
from contextlib import contextmanager
from pathlib import Path

from modalctl.outdir import OutDirError, atomic, check_writable
from modalctl.plugin.command import grid_points
from modalctl.units import number_type

__all__ = ["BAD_INPUT", "UNREACHABLE", "DEVICE", "INTERNAL", "MODES_MAX", "parse_param", "points", "modes",
           "out_dir", "out_file", "picture_file", "option_type", "progress_bars", "stage", "Interrupted",
           "interruptible", "add_target", "model_and_shape", "open_device", "refuse", "internal_error", "jsonable",
           "write_json", "identity", "identity_defaults"]

BAD_INPUT, UNREACHABLE, DEVICE, INTERNAL = 2, 1, 3, 4  # docs/errors.md
MODES_MAX = 1000
points = grid_points  # --points: N for a beam, NxM for a plate


def parse_param(text: str) -> tuple[str, str]:
    """``--param NAME=VALUE`` -> (name, value text); the value's units are the shape's to read."""
    if "=" not in text:
        raise argparse.ArgumentTypeError(f"expected name=value, got {text!r}")
    name, value = text.split("=", 1)
    return name.strip(), value.strip()


def modes(text: str):
    """``--modes``: auto, all or a number of modes."""
    if text in ("auto", "all"):
        return text
    try:
        count = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected auto, all or a number of modes, got {text!r}") from None
    if not 1 <= count <= MODES_MAX:
        raise argparse.ArgumentTypeError(f"modes must lie in [1, {MODES_MAX}], got {text!r}")
    return count


def out_dir(text: str) -> str:
    """``--out``: a directory to write into (made if absent); not empty, not an existing file, a
    place results can be written (:func:`modalctl.outdir.check_writable`)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("out: give a directory (an empty name would write into the working one)")
    return _writable(text, folder=True)


def out_file(text: str) -> str:
    """An option naming a file to write (a model file, a picture): not empty, not a directory nor
    a device, in a folder results can be written to (made if absent)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("give a file name")
    return _writable(text, folder=False)


def picture_file(text: str) -> str:
    """An option naming a picture to write: an :func:`out_file` ending in ``.png`` (the pictures are PNG:
    ``out.pdf`` had reached matplotlib's writer with PNG's options and ended in a TypeError)."""
    if not text.lower().endswith(".png"):
        raise argparse.ArgumentTypeError(f"pictures are PNG: give a file ending in .png, got {text!r}")
    return out_file(text)


def _writable(text: str, folder: bool) -> str:
    try:
        check_writable(text, folder)
    except OutDirError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def progress_bars(args) -> bool:
    """Whether a command draws progress bars: on a terminal only (a log or a pipe would keep every
    carriage-return frame), and not with ``--quiet``."""
    return not getattr(args, "quiet", False) and sys.stderr.isatty()


def stage(args, text: str) -> None:
    """Where there are no bars (stderr is not a terminal), one line on stderr as a stage starts,
    for a log to say where a command is; nothing with ``--quiet``."""
    if not getattr(args, "quiet", False) and not sys.stderr.isatty():
        print(f"modalctl {args.command}: {text}", file=sys.stderr, flush=True)


class Interrupted(KeyboardInterrupt):
    """A signal asked the command to stop (SIGINT, SIGTERM, SIGHUP: Ctrl-C, ``kill``, ``timeout``, a
    closed terminal, a cancelled CI job): it ends as Ctrl-C ends it, a shot through the supervisor's
    ramp-down, with exit code 128 + the signal's number (the shell's: 130, 143, 129)."""

    def __init__(self, signum: int):
        super().__init__(f"interrupted by {signal.Signals(signum).name}")
        self.signum, self.code = signum, 128 + signum


STOPPING_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


@contextmanager
def interruptible():
    """While the block runs, the first of :data:`STOPPING_SIGNALS` raises :class:`Interrupted` in
    the main thread; those after it are ignored (the stop is under way: a second Ctrl-C must not
    break the ramp-down). The previous handlers are back after the block."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    heard: list[int] = []

    def stop(signum, frame):
        if not heard:
            heard.append(signum)
            raise Interrupted(signum)

    previous = {number: signal.signal(number, stop) for number in STOPPING_SIGNALS}
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)


def add_target(p) -> None:
    """Arguments shared by decompose and run: where the model and the shape come from."""
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--scene", help="scene name (see 'modalctl scenes')")
    source.add_argument("--model", help="modal model file (.npz written by modalctl)")
    p.add_argument("--shape", required=True, help="shape generator (see 'modalctl plugins')")
    p.add_argument("--param", action="append", default=[], type=parse_param, metavar="NAME=VALUE",
                   help="shape parameter with units, e.g. width=18mm (repeatable)")
    p.add_argument("--modes", type=modes, default="auto",
                   help="auto (smallest set meeting the target), all, or N (the N lowest modes)")
    p.add_argument("--tau-target", type=number_type(float, "tau-target", low=0, high=1),
                   help="auto: least tau for the kept modes (default 0.98)")
    p.add_argument("--points", type=points, help="grid points: N for a beam, NxM for a plate (default: the scene's)")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def model_and_shape(args):
    """The model (``--scene`` or ``--model``) and the target shape (``--shape``, ``--param``)."""
    from modalctl.model.modes import ModalModel
    from modalctl.model.scenes import load_scene
    from modalctl.model.shape import generated
    from modalctl.plugin.manager import get_shape

    model = load_scene(args.scene, args.points) if args.scene is not None else ModalModel.load(args.model)
    return model, generated(get_shape(args.shape), model.grid, dict(args.param))


def open_device(args, model=None, shape=None):
    """The device at ``--transport`` with its transport's own options; another transport's are refused.
    A transport that refuses what it was given (its URL, its options: the simulator's truth) with a
    plain ValueError refuses bad input (exit 2), as an :class:`~modalctl.errors.InputError` would."""
    from urllib.parse import urlsplit

    from modalctl.errors import InputError
    from modalctl.io.device import DeviceContext
    from modalctl.io.device import open_device as open_url
    from modalctl.model.shape import ParamError

    scheme = urlsplit(args.transport).scheme
    misplaced = args.transports.misplaced(args, scheme)
    if misplaced:
        raise ParamError(f"{', '.join(misplaced)}: not an option of {scheme}:// (--transport {args.transport})")
    try:
        return open_url(args.transport, DeviceContext(model, shape, args.transports.of(args, scheme)))
    except InputError:
        raise
    except ValueError as refused:  # a transport plugin's (or its library's: pyserial's baud) refusal of its input
        raise InputError(f"{args.transport}: {refused}") from refused


def refuse(command: str, code: int, message: str, as_json: bool, certificate=None, stderr: bool = True) -> int:
    """Say why a command ends with ``code``: on stderr, and with ``--json`` as ``{"error", "code"}``
    (and the certificate of a refused plan) on stdout. Returns ``code``."""
    if stderr:
        print(f"modalctl {command}: {message}", file=sys.stderr)
    if as_json:
        body = {"error": message, "code": code, "command": command}
        if certificate:
            body["certificate"] = certificate
        print(json.dumps(body, default=jsonable))
    return code


INTERNAL_ERROR_FILE = "internal-error.txt"  # in the folder the command claimed, else a temporary file


def internal_error(command: str, exc: BaseException, as_json: bool, folder: Path | None = None,
                   culprit: str = "modalctl") -> int:
    """End a command that raised what no check of its input raises (a bug in ``culprit``): its
    traceback into ``folder/internal-error.txt`` (the folder the command claimed, if any) or a
    temporary file, and one line on stderr saying where, never the traceback. Returns
    :data:`INTERNAL`."""
    import platform
    import traceback

    from modalctl import __version__

    said = " ".join(str(exc).split()) or "(no message)"
    text = (f"modalctl {command}: internal error (a bug in {culprit}); modalctl {__version__}, Python "
            f"{platform.python_version()}\n\n" + "".join(traceback.format_exception(type(exc), exc, exc.__traceback__)))
    where = _traceback_written(text, command, folder)
    return refuse(command, INTERNAL, f"internal error: {type(exc).__name__}: {said} (a bug in {culprit}; "
                  + (f"the traceback is in {where})" if where else "its traceback could not be written)"), as_json)


def _traceback_written(text: str, command: str, folder: Path | None) -> Path | None:
    """Where ``text`` was written: ``folder``'s internal-error.txt (recorded in its manifest, so the
    next run there removes it), else a new file in the system's temporary folder; None if neither
    could be written."""
    import tempfile

    from modalctl.outdir import record

    if folder is not None:
        try:
            with atomic(folder / INTERNAL_ERROR_FILE) as temporary:
                temporary.write_text(text)
            record(folder, [INTERNAL_ERROR_FILE])
            return folder / INTERNAL_ERROR_FILE
        except (OSError, OutDirError):
            pass
    try:
        name = "".join(c for c in command if c.isalnum() or c in "-_")[:40] or "command"
        with tempfile.NamedTemporaryFile("w", prefix=f"modalctl-{name}-internal-error-",
                                         suffix=".txt", delete=False) as file:
            file.write(text)
        return Path(file.name)
    except OSError:
        return None


def jsonable(value):
    """``json.dumps``'s ``default``: numpy scalars and arrays as numbers and lists, anything else as text."""
    import numpy as np

    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)


def write_json(path: Path, value) -> None:
    """``value`` as JSON at ``path``, atomically (see :mod:`modalctl.outdir`)."""
    with atomic(path) as temporary:
        temporary.write_text(json.dumps(value, indent=2, default=jsonable))


def identity(args) -> dict:
    """The options that make a run what it is (not how it is shown): a folder holding results of
    other options holds another run."""
    shown = {"quiet", "force", "json", "no_plots", "transports", "out", "command"}
    return {k: v for k, v in sorted(vars(args).items()) if k not in shown and not callable(v)}


def option_type(command: str, option: str):
    """The type ``command``'s parser reads ``option`` with (its units and range): for a value
    another command takes as text (``sweep --vary``), checked as that option would check it."""
    from modalctl.cli import command_parser

    return next(action.type for action in command_parser(command)._actions if option in action.option_strings)


def identity_defaults(command: str) -> dict:
    """Every option of ``command`` at its default (its transports' own included)."""
    from modalctl.cli import command_parser

    parser = command_parser(command)
    return {action.dest: parser.get_default(action.dest) for action in parser._actions
            if action.dest != argparse.SUPPRESS}
