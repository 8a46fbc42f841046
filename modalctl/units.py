"""Parse physical quantities at the edges (``18mm``, ``25ms``, ``1%``) into SI floats.

Everything inside ``modalctl`` is SI: metres, seconds, hertz, volts. Text with units only
enters through :func:`parse_quantity`, which raises :class:`UnitError` naming the field; the
command line's options (and transports' own, see :mod:`modalctl.io.device`) read it through
:func:`quantity_type` and :func:`number_type`. A foundation module: it imports nothing of modalctl but
:mod:`modalctl.errors`.
"""

from __future__ import annotations

import argparse
import math
import re
from dataclasses import dataclass
from typing import Any, Callable

from modalctl.errors import InputError

__all__ = ["UnitError", "parse_quantity", "parse_point", "quantity_type", "number_type", "DIMENSIONS"]

_PREFIXES = {"n": 1e-9, "u": 1e-6, "\u00b5": 1e-6, "m": 1e-3, "c": 1e-2, "k": 1e3, "M": 1e6}


def _with_prefixes(base: str, allowed: str) -> dict[str, float]:
    table = {base: 1.0}
    for p in allowed:
        table[p + base] = _PREFIXES[p]
    return table


#: Accepted unit symbols per dimension, with their factor to SI.
DIMENSIONS: dict[str, dict[str, float]] = {
    "m": _with_prefixes("m", "nu\u00b5mck"),
    "s": _with_prefixes("s", "nu\u00b5m"),
    "Hz": _with_prefixes("Hz", "kM"),
    "V": _with_prefixes("V", "mk"),
    "m/s": _with_prefixes("m/s", "u\u00b5mc"),
    "1": {"": 1.0, "%": 1e-2, "ppm": 1e-6},
    "1/s": {"1/s": 1.0, "/s": 1.0, "%/s": 1e-2, "%/ms": 10.0, "ppm/s": 1e-6},
    "kg/m": {"kg/m": 1.0, "g/m": 1e-3, "g/mm": 1.0, "kg/mm": 1e3},
    "kg/m^2": {"kg/m^2": 1.0, "kg/m2": 1.0, "kg/m\u00b2": 1.0, "g/m^2": 1e-3, "g/m2": 1e-3, "g/cm^2": 10.0,
               "g/cm2": 10.0},
    "V/s": {"V/s": 1.0, "V/ms": 1e3, "V/us": 1e6, "V/\u00b5s": 1e6, "kV/s": 1e3, "MV/s": 1e6},
    "N s/m": {"N s/m": 1.0, "Ns/m": 1.0, "N*s/m": 1.0, "kg/s": 1.0},
    "N s/m/s": {"N s/m/s": 1.0, "Ns/m/s": 1.0, "N s/m/ms": 1e3, "Ns/m/ms": 1e3},  # a damping's rate of change
    "Pa": {"Pa": 1.0, "kPa": 1e3, "MPa": 1e6, "GPa": 1e9},
    "kg/m^3": {"kg/m^3": 1.0, "kg/m3": 1.0, "kg/m\u00b3": 1.0, "g/cm^3": 1e3, "g/cm3": 1e3},
    "N/m^2": {"N/m^2": 1.0, "N/m2": 1.0, "kN/m^2": 1e3, "MN/m^2": 1e6, "GN/m^2": 1e9},  # a rim's stiffness per length
    "N": {"N": 1.0, "mN": 1e-3, "kN": 1e3, "Nm/m": 1.0, "N m/m": 1.0},  # a rim's rotational stiffness per length
}

_NUMBER = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(.*?)\s*$")


class UnitError(InputError):
    """A value with a missing, unknown or mismatched unit."""


def parse_quantity(value, unit: str, name: str = "value") -> float:
    """Return ``value`` in SI units of dimension ``unit``.

    Parameters
    ----------
    value : str or float
        ``"18mm"``, ``"18 mm"``, ``"0.018"`` or a number (already SI).
    unit : str
        Dimension key of :data:`DIMENSIONS` (``"m"``, ``"s"``, ``"Hz"``, ``"V"``, ``"m/s"``, ``"1"``).
    name : str
        Field name used in error messages.

    Returns
    -------
    float
        The value in SI units (for ``"1"``: a plain fraction, ``"1%"`` -> 0.01); always finite.
    """
    si = _si(value, unit, name)
    if not math.isfinite(si):  # "1e400mm" overflows to infinity: no quantity is that
        raise UnitError(f"{name}: {value!r} is not a finite number")
    return si


def _si(value, unit: str, name: str) -> float:
    table = DIMENSIONS[unit]
    if isinstance(value, bool):
        raise UnitError(f"{name}: expected a number with unit {unit!r}, got {value!r}")
    if isinstance(value, (int, float)):
        return float(value)
    match = _NUMBER.match(str(value))
    if not match:
        example = "18mm" if unit == "m" else f"18{next((s for s in table if s), '')}"  # in the option's own unit
        raise UnitError(f"{name}: cannot read {value!r} as a number with unit {unit!r} (example: {example})")
    number, symbol = float(match.group(1)), match.group(2)
    if symbol == "":
        return number  # a bare number is already SI
    if symbol not in table:
        known = ", ".join(repr(s) for s in table if s) or "none"
        raise UnitError(f"{name}: unknown unit {symbol!r} in {value!r}; {unit!r} accepts {known}")
    return number * table[symbol]


def parse_point(value, unit: str, name: str = "value") -> tuple[float, ...]:
    """Parse one or more comma-separated quantities (``"24mm"`` or ``"24mm,10mm"``) into a tuple."""
    if isinstance(value, (int, float, str)):
        parts = str(value).split(",") if isinstance(value, str) else [value]
    else:
        parts = list(value)
    return tuple(parse_quantity(p, unit, name) for p in parts)


@dataclass(frozen=True)
class Bounds:
    """What an option's type accepts: values of dimension ``unit`` in ``(low, high]`` (``[low, high]``
    when not ``low_open``; ``low`` None: unbounded below), of ``kind``; kept on the parser so that
    tests and documentation read the ranges from where they are enforced."""

    unit: str
    low: float | None
    high: float
    low_open: bool
    point: bool = False
    kind: type = float

    def holds(self, value: float) -> bool:
        """Whether ``value`` (SI) is accepted."""
        above = True if self.low is None else (self.low < value if self.low_open else self.low <= value)
        return math.isfinite(value) and above and value <= self.high


def quantity_type(unit: str, name: str, *, low: float | None = None, high: float = math.inf,
                  low_open: bool = True, point: bool = False) -> Callable[[str], Any]:
    """An argparse ``type`` reading text with units of dimension ``unit`` into SI, refusing values
    outside ``(low, high]`` (``[low, high]`` when not ``low_open``; no lower bound when ``low`` is
    None), with messages that name the option. ``point``: comma-separated coordinates (a tuple)."""
    reader = parse_point if point else parse_quantity

    def parse(text: str):
        try:
            value = reader(text, unit, name)
        except UnitError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
        if low is not None and not point and not ((low < value if low_open else low <= value) and value <= high):
            span = f"{'(' if low_open else '['}{low:g}, {high:g}{']' if math.isfinite(high) else ')'}"
            raise argparse.ArgumentTypeError(f"{name} must lie in {span}, got {text!r}")
        return value

    parse.__name__ = name  # argparse's "invalid <name> value" for text it cannot read
    parse.bounds = Bounds(unit, low, high, low_open, point)
    return parse


def number_type(kind: type, name: str, *, low: float, high: float = math.inf,
                low_open: bool = True) -> Callable[[str], Any]:
    """An argparse ``type`` reading a plain number (``int`` or ``float``, no unit) within bounds, as
    :func:`quantity_type`."""
    def parse(text: str):
        value = kind(text)  # ValueError: argparse's "invalid <name> value: <text>"
        if not (math.isfinite(value) and (low < value if low_open else low <= value) and value <= high):
            span = f"{'(' if low_open else '['}{low:g}, {high:g}{']' if math.isfinite(high) else ')'}"
            raise argparse.ArgumentTypeError(f"{name} must lie in {span}, got {text!r}")
        return value

    parse.__name__ = name
    parse.bounds = Bounds("1", low, high, low_open, False, kind)
    return parse
