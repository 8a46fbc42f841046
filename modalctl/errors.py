"""Whose fault a refusal is: :class:`InputError`, what the user gave is wrong (an option, a unit, a
file, an output path), which the command line ends with exit code 2; any other exception that
escapes a command is a bug in modalctl (exit code 4, its traceback written to a file; see
``docs/errors.md``).

Every check at the edge raises :class:`InputError` or one of its subclasses
(:class:`~modalctl.model.modes.ModelError`, :class:`~modalctl.model.shape.ParamError`,
:class:`~modalctl.units.UnitError`, :class:`~modalctl.outdir.OutDirError`); a check of the core's
own contracts (an array of the wrong shape from a caller inside modalctl) stays a plain
``ValueError``. A foundation module: it imports nothing, so every layer can import it.
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Iterator

__all__ = ["InputError", "inputs_checked"]


class InputError(ValueError):
    """What the user gave is wrong: an option, a unit, a name, a file, an output path. The message
    names it and what it accepts. A ``ValueError``, so callers that catch ``ValueError`` (argparse's
    types among them) still take it."""


@contextmanager
def inputs_checked(where: str = "") -> Iterator[None]:
    """A plain ``ValueError`` raised in the block becomes an :class:`InputError` of the same message
    (``where: message`` when ``where`` is given), chained to it: for a call whose only
    ``ValueError`` is a check of what the user gave, in a module that does not raise
    :class:`InputError` yet. Its subclasses (an :class:`InputError`, a ``PlanError``...) pass
    through unchanged."""
    try:
        yield
    except ValueError as exc:
        if type(exc) is not ValueError:
            raise
        raise InputError(f"{where}: {exc}" if where else str(exc)) from exc
