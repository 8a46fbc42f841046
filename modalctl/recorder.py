"""The run log: every control period appended to disk as it happens, so that a crash loses nothing.

A log is two files side by side: ``NAME.json`` says what one record holds (field names, numpy
dtypes, shapes, units) and ``NAME.bin`` is the records, back to back, little-endian, written and
flushed to the operating system each period. :func:`read_log` reads whatever whole records are
on disk, also from a run that died in the middle of one. No pickle: any language can read it.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

__all__ = ["Recorder", "read_log", "LOG_VERSION"]

LOG_VERSION = 1


class Recorder:
    """Appends one record per control period.

    Parameters
    ----------
    path : str or Path
        Log name without suffix; ``path.json`` and ``path.bin`` are written.
    fields : dict
        ``name -> (dtype, shape, unit)`` of each record's fields, e.g.
        ``{"measured": ("<c16", (k,), "m/s sqrt(kg)")}``.
    meta : dict, optional
        Anything JSON can hold that a reader of the log needs (rates, modes, scenario).
    """

    def __init__(self, path, fields: dict, meta: dict | None = None):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.dtype = np.dtype([(name, np.dtype(dt).newbyteorder("<"), tuple(shape))
                               for name, (dt, shape, _) in fields.items()])
        header = {"version": LOG_VERSION, "record_bytes": self.dtype.itemsize,
                  "fields": [{"name": name, "dtype": np.dtype(dt).newbyteorder("<").str, "shape": list(shape),
                              "unit": unit} for name, (dt, shape, unit) in fields.items()],
                  "meta": meta or {}}
        self.path.with_suffix(".json").write_text(json.dumps(header, indent=1))
        self._file = open(self.path.with_suffix(".bin"), "wb")
        self._record = np.zeros(1, self.dtype)
        self._fields = {name: self._record[name][0] if self._record[name][0].ndim else self._record[name]
                        for name in self.dtype.names}  # writable views into the one record
        self.records = 0

    def write(self, **values) -> None:
        """Append one record (fields not given are zero) and hand it to the operating system."""
        if len(values) != len(self._fields):
            self._record[...] = 0
        for name, value in values.items():
            self._fields[name][...] = value
        self._file.write(self._record.data)
        self._file.flush()
        self.records += 1

    def close(self) -> None:
        if not self._file.closed:
            self._file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def read_log(path) -> tuple[np.ndarray, dict]:
    """The whole records of a log and its header.

    Returns
    -------
    records : structured ndarray, shape (n,)
        ``records["measured"]`` etc.; a half-written last record is left out.
    header : dict
    """
    path = Path(path)
    header = json.loads(path.with_suffix(".json").read_text())
    if header.get("version") != LOG_VERSION:
        raise ValueError(f"{path}: log version {header.get('version')!r}, this reader knows {LOG_VERSION}")
    dtype = np.dtype([(f["name"], np.dtype(f["dtype"]), tuple(f["shape"])) for f in header["fields"]])
    raw = path.with_suffix(".bin").read_bytes()
    whole = len(raw) // dtype.itemsize
    return np.frombuffer(raw[:whole * dtype.itemsize], dtype), header
