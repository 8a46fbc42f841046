"""A command a plugin adds to ``modalctl`` (hook ``modalctl_commands``), and how the command line finds them.

A command is a :class:`Command`: a name, a line of help, ``add_arguments(parser)`` and
``run(args) -> int`` (the exit code). Command plugins register under their own entry point group,
``modalctl.commands``, not ``modalctl``: the command line loads that group to list its commands
before it parses anything, and loading every plugin there would make ``modalctl --help`` pay for
every plugin's imports (numpy, scipy, the simulator: a second). So a command plugin's module
imports only what declaring the command needs, and the rest inside ``add_arguments`` and
``run`` (see :mod:`modalctl.hil.commands`).

A light module: argparse, abc and pluggy, nothing numerical. :func:`grid_points` is here because
the command line's own commands and the plugins' read grids the same way.
"""

from __future__ import annotations

import argparse
import math
from abc import ABC, abstractmethod
from functools import lru_cache

import pluggy

from . import spec as hookspecs

__all__ = ["Command", "COMMAND_GROUP", "command_manager", "plugin_commands", "grid_points", "POINTS_MAX"]

COMMAND_GROUP = "modalctl.commands"
POINTS_MAX = 1_000_000  # grid points of a scene (a 1000 x 1000 plate)


class Command(ABC):
    """One ``modalctl`` command.

    Attributes
    ----------
    name : str
        The word users type (``modalctl NAME ...``); unique across the command line.
    help : str
        One line for ``modalctl --help``.
    description : str or None
        The paragraph of ``modalctl NAME --help`` (``help`` when None).
    """

    name: str = ""
    help: str = ""
    description: str | None = None

    @abstractmethod
    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Declare the command's options on ``parser`` (called only when the command is chosen or
        its options listed: import what the options need here, not at the module's top)."""

    @abstractmethod
    def run(self, args: argparse.Namespace) -> int:
        """Do the command with its parsed options; returns the exit code (0 success, 2 bad input;
        raise :class:`modalctl.model.shape.ParamError` or ``ValueError`` for bad input, and the
        command line says so and exits 2)."""


@lru_cache(maxsize=None)
def command_manager() -> pluggy.PluginManager:
    """The plugin manager of the command plugins (entry point group ``modalctl.commands``) alone."""
    manager = pluggy.PluginManager("modalctl")
    manager.add_hookspecs(hookspecs)
    manager.load_setuptools_entrypoints(COMMAND_GROUP)
    return manager


def plugin_commands(manager: pluggy.PluginManager | None = None) -> dict[str, Command]:
    """The commands installed plugins add, by name, in the order found."""
    found: dict[str, Command] = {}
    for group in (manager or command_manager()).hook.modalctl_commands():
        for command in group:
            if command.name in found:
                from .manager import PluginError

                raise PluginError(f"command {command.name!r} is provided by two plugins")
            found[command.name] = command
    return found


def grid_points(text: str):
    """``--points``: ``211`` for a beam, ``101x71`` (or ``101,71``) for a plate."""
    try:
        parts = [int(v) for v in text.lower().replace("x", ",").split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"points: expected N (a beam) or NxM (a plate), got {text!r}") from None
    if len(parts) > 2 or min(parts) < 2 or math.prod(parts) > POINTS_MAX:
        raise argparse.ArgumentTypeError(f"points: N or NxM with at least 2 per side and at most {POINTS_MAX:,} "
                                         f"in all, got {text!r}")
    return parts[0] if len(parts) == 1 else tuple(parts)
