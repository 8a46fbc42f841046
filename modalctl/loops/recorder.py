"""The run log: every control period kept on disk as it happens, so that a crash loses nothing.

A log is two files side by side: ``NAME.json`` says what one record holds (field names, numpy
dtypes, shapes, units) and ``NAME.bin`` holds the records. The ``.bin`` file is mapped into
memory: a record written is in the operating system's page cache at once, so a crash of the
process loses nothing, without a system call each period (a write and a flush cost ~15 us, a
tenth of a 10 kHz period, more than the record). Its first 8 bytes count the whole records
(little-endian int64), updated after each; the records follow, back to back, little-endian. The
file grows by doubling and is cut to its records when closed. :func:`read_log` reads the counted
records, also from a run that died in the middle of one. No pickle: any language can read it.
"""

from __future__ import annotations

import json
import mmap
from pathlib import Path

import numpy as np

from modalctl.errors import InputError
from modalctl.outdir import atomic

__all__ = ["Recorder", "read_log", "LOG_VERSION"]

LOG_VERSION = 2  # 1: the records back to back, no count (still read)
COUNT_BYTES = 8


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
    capacity : int
        Records the file first has room for (it doubles when full).
    """

    def __init__(self, path, fields: dict, meta: dict | None = None, capacity: int = 1024):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.dtype = np.dtype([(name, np.dtype(dt).newbyteorder("<"), tuple(shape))
                               for name, (dt, shape, _) in fields.items()])
        header = {"version": LOG_VERSION, "record_bytes": self.dtype.itemsize, "count_bytes": COUNT_BYTES,
                  "fields": [{"name": name, "dtype": np.dtype(dt).newbyteorder("<").str, "shape": list(shape),
                              "unit": unit} for name, (dt, shape, unit) in fields.items()],
                  "meta": meta or {}}
        with atomic(self.path.with_suffix(".json")) as temporary:
            temporary.write_text(json.dumps(header, indent=1))
        binary = self.path.with_suffix(".bin")
        if binary.is_symlink():  # never written through: the link goes, a file of ours takes its place
            binary.unlink()
        self._file = open(binary, "w+b")
        self._map: mmap.mmap | None = None
        self.records = 0
        self._room(max(1, int(capacity)))

    def _room(self, capacity: int) -> None:
        """Map the file with room for ``capacity`` records (the new room is zeros)."""
        old, self._columns, self._count = self._map, None, None  # our views of the old map go first
        if old is not None:
            old.close()
        self._file.truncate(COUNT_BYTES + capacity * self.dtype.itemsize)
        self._map = mmap.mmap(self._file.fileno(), 0)
        self._count = np.frombuffer(self._map, "<i8", 1)
        rows = np.frombuffer(self._map, self.dtype, capacity, offset=COUNT_BYTES)
        self._columns = {name: rows[name] for name in self.dtype.names}  # writable views, one per field
        self._capacity = capacity

    def write(self, **values) -> None:
        """Append one record (fields not given are zero): in the page cache when this returns."""
        if self._map is None:
            raise ValueError(f"{self.path}: the log is closed")
        if self.records == self._capacity:
            self._room(2 * self._capacity)
        n = self.records
        for name, value in values.items():
            self._columns[name][n] = value
        self.records = self._count[0] = n + 1  # the record is whole: count it

    def close(self) -> None:
        """Unmap and cut the file to its records."""
        if self._map is None:
            return
        self._columns = self._count = None
        self._map.close()
        self._map = None
        self._file.truncate(COUNT_BYTES + self.records * self.dtype.itemsize)
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
        ``records["measured"]`` etc.: the records the writer counted (one it was writing when it
        died is left out).
    header : dict
    """
    path = Path(path)
    header = json.loads(path.with_suffix(".json").read_text())
    version = header.get("version")
    if version not in (1, LOG_VERSION):
        raise InputError(f"{path}: log version {version!r}, this reader knows 1 and {LOG_VERSION}")
    dtype = np.dtype([(f["name"], np.dtype(f["dtype"]), tuple(f["shape"])) for f in header["fields"]])
    raw = path.with_suffix(".bin").read_bytes()
    start = header.get("count_bytes", 0)
    whole = max(0, len(raw) - start) // dtype.itemsize
    if start:  # the count the writer keeps after each whole record
        whole = min(whole, int.from_bytes(raw[:start], "little")) if len(raw) >= start else 0
    return np.frombuffer(raw[start:start + whole * dtype.itemsize], dtype), header
