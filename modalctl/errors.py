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

__all__ = ["InputError"]


class InputError(ValueError):
    """What the user gave is wrong: an option, a unit, a name, a file, an output path. The message
    names it and what it accepts. A ``ValueError``, so callers that catch ``ValueError`` (argparse's
    types among them) still take it."""
