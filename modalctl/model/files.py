"""Mode shapes from other programs' files: CSV tables and universal files (UFF 55).

What these readers return is turned into a :class:`~modalctl.model.modes.ModalModel` by the caller
(``modalctl decompose --model``, the identification); ``.npz`` models written by modalctl itself
are read by :meth:`ModalModel.load <modalctl.model.modes.ModalModel.load>`.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from .modes import ModelError, check_finite

__all__ = ["read_shapes_csv", "read_uff_sets", "read_uff55", "CSV_BYTES_MAX"]
CSV_BYTES_MAX = 256 * 10**6  # a table of shapes larger than this is not a haptic surface's


def read_shapes_csv(path) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Read mode shapes from a CSV file.

    The header names the coordinate columns ``x`` (and ``y`` for plates), in metres, then one
    column per mode. Returns ``points`` (n, d), ``shapes`` (k, n) and the mode column names.
    """
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"csv: no such file {str(path)!r}")
    if path.stat().st_size > CSV_BYTES_MAX:
        raise ModelError(f"csv: {str(path)!r} is {path.stat().st_size / 1e6:.0f} MB, above {CSV_BYTES_MAX / 1e6:.0f} MB")
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            rows = [row for row in csv.reader(handle) if row and not row[0].lstrip().startswith("#")]
    except (UnicodeDecodeError, csv.Error) as exc:  # a binary file, NUL bytes
        raise ModelError(f"csv: {str(path)!r} is not a text table ({exc})") from None
    if len(rows) < 2:
        raise ModelError(f"csv: {str(path)!r} needs a header and at least one row")
    header = [h.strip() for h in rows[0]]
    ncoord = 2 if len(header) > 1 and header[1].lower() == "y" else 1
    if header[0].lower() != "x" or len(header) <= ncoord:
        raise ModelError(f"csv: header must be 'x[,y],mode...' , got {header}")
    try:
        table = np.array([[float(v) for v in row] for row in rows[1:]])
    except ValueError as exc:
        raise ModelError(f"csv: {str(path)!r}: {exc}") from None
    if table.ndim != 2 or table.shape[1] != len(header):
        raise ModelError(f"csv: every row of {str(path)!r} needs {len(header)} values")
    check_finite(f"csv {path.name}", table)
    return table[:, :ncoord], table[:, ncoord:].T.copy(), header[ncoord:]


def read_uff_sets(path) -> list[dict]:
    """Every dataset of a universal file as pyuff's dicts (needs the optional ``pyuff``)."""
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"uff: no such file {str(path)!r}")
    try:
        import pyuff
    except ImportError:
        raise ModelError("uff: reading UFF files needs pyuff: pip install 'modalctl[uff]'") from None
    sets = pyuff.UFF(str(path)).read_sets()
    return sets if isinstance(sets, list) else [sets]


def read_uff55(path, component: str = "r3") -> dict:
    """Read normal-mode shapes from a UFF dataset-55 file (needs the optional ``pyuff``).

    Returns a dict with ``node_nums`` (n,), ``frequencies`` (k,) in Hz, ``damping`` (k,)
    (viscous ratio, NaN where absent) and ``shapes`` (k, n) from the chosen response component.
    """
    sets = [s for s in read_uff_sets(path) if s.get("type") == 55]
    if not sets:
        raise ModelError(f"uff: {str(path)!r} holds no dataset 55")
    nodes = np.asarray(sets[0]["node_nums"], dtype=int)
    freqs, damp, shapes = [], [], []
    for s in sets:
        if not np.array_equal(np.asarray(s["node_nums"], dtype=int), nodes):
            raise ModelError(f"uff: mode {s.get('mode_n')} uses other nodes than the first mode")
        freqs.append(float(s.get("freq", np.nan)))
        damp.append(float(s.get("modal_damp_vis", np.nan)))
        shapes.append(np.real(np.asarray(s[component], dtype=complex)))
    return {"node_nums": nodes, "frequencies": np.array(freqs), "damping": np.array(damp),
            "shapes": np.array(shapes)}
