"""Mode shapes from other programs' files (CSV tables, universal files), and what every reader
of a file checks before it reads: the arrays a ``.npy`` or ``.npz`` file declares, bounded by
their file and by the memory there is.

What these readers return is turned into a :class:`~modalctl.model.modes.ModalModel` by the caller
(``modalctl decompose --model``, the identification); ``.npz`` models written by modalctl itself
are read by :meth:`ModalModel.load <modalctl.model.modes.ModalModel.load>`, which checks them with
:func:`check_npz`. A damaged file is a :class:`~modalctl.model.modes.ModelError` naming it, never
numpy's, zipfile's or pyuff's own exception.
"""

from __future__ import annotations

import csv
import re
import zipfile
import zlib
from pathlib import Path

import numpy as np

from .modes import ModelError, check_finite

__all__ = ["read_shapes_csv", "read_uff_sets", "read_uff55", "read_npy", "check_npz", "memory_available",
           "CSV_BYTES_MAX", "UFF_BYTES_MAX", "NPY_BYTES_MAX"]
CSV_BYTES_MAX = 256 * 10**6  # a table of shapes larger than this is not a haptic surface's
UFF_BYTES_MAX = 2**31  # pyuff reads a whole universal file into memory, then parses it
NPY_BYTES_MAX = 2**30  # one field of values on a grid: 130 million points
UFF_DELIMITER = re.compile(rb"^    -1 *\r?$", re.M)  # a dataset's first and last line (pyuff's own test)
NPZ_COMPRESSION = (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED)  # what numpy writes


def memory_available() -> int | None:
    """Bytes the kernel can give without swapping (``MemAvailable``), None where it does not say."""
    try:
        with open("/proc/meminfo") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _check_bytes(name: str, declared: int, most: int) -> None:
    """Refuse to read ``declared`` bytes for ``name`` beyond ``most`` or the memory available."""
    available = memory_available()
    if declared > most:
        raise ModelError(f"{name} declares {declared / 2**30:.3g} GiB of arrays; at most {most / 2**30:g} GiB: "
                         "refused unread")
    if available is not None and declared > available:
        raise ModelError(f"{name} declares {declared / 2**30:.3g} GiB of arrays, more than the "
                         f"{available / 2**30:.3g} GiB of memory available: refused unread")


def _npy_header(stream, name: str, kinds: str = "biuf") -> tuple[int, int]:
    """The bytes the array of an ``.npy`` stream declares, and the length of its header; a stream
    that is not an ``.npy`` array of ``kinds`` (numpy's dtype kinds: real numbers) is refused."""
    try:
        version = np.lib.format.read_magic(stream)
        if version not in ((1, 0), (2, 0)):
            raise ValueError(f"format version {version}")
        read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        shape, _, dtype = read(stream)
    except (ValueError, EOFError, OSError, SyntaxError) as exc:
        raise ModelError(f"{name} is not a .npy array ({exc})") from None
    if dtype.hasobject or dtype.kind not in kinds:
        raise ModelError(f"{name} holds {dtype}, not {'real numbers' if kinds == 'biuf' else 'numbers or text'}")
    return int(np.prod(shape, dtype=object)) * dtype.itemsize, stream.tell()


def read_npy(path, name: str = "npy", most: int = NPY_BYTES_MAX) -> np.ndarray:
    """The array of the ``.npy`` file at ``path``, its size checked from its header first (at most
    ``most`` bytes, no more than its file holds, no more than the memory available)."""
    path = Path(path)
    where = f"{name}: {str(path)!r}"
    if not path.is_file():
        raise ModelError(f"{name}: no such file {str(path)!r}")
    try:
        with path.open("rb") as handle:
            if zipfile.is_zipfile(handle):
                raise ModelError(f"{where} is a zip archive (an .npz?), not a .npy array")
            handle.seek(0)
            declared, header = _npy_header(handle, where)
            if header + declared > path.stat().st_size:
                raise ModelError(f"{where} declares {declared} bytes of data and holds "
                                 f"{path.stat().st_size - header}: truncated or damaged")
            _check_bytes(where, declared, most)
            handle.seek(0)
            return np.load(handle, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        if isinstance(exc, ModelError):
            raise
        raise ModelError(f"{where} cannot be read ({exc})") from None


def check_npz(path, name: str, most: int) -> None:
    """Refuse an ``.npz`` archive before reading an array of it: not a zip, encrypted or compressed
    otherwise than numpy does, a member that is not an ``.npy`` array of numbers or declares more
    than it holds, or more than ``most`` bytes in all (or than the memory available)."""
    total = 0
    try:
        with zipfile.ZipFile(path) as archive:
            for info in archive.infolist():
                if info.flag_bits & 0x1 or info.compress_type not in NPZ_COMPRESSION:
                    raise ModelError(f"{name}: member {info.filename!r} is encrypted or compressed otherwise "
                                     "than numpy writes")
                with archive.open(info) as member:
                    declared, header = _npy_header(member, f"{name}: member {info.filename!r}", "biufU")
                if header + declared > info.file_size:
                    raise ModelError(f"{name}: member {info.filename!r} declares {declared} bytes and holds "
                                     f"{info.file_size - header}: truncated or damaged")
                total += declared
                _check_bytes(f"{name} ({info.filename} and before)", total, most)
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError) as exc:
        if isinstance(exc, ModelError):
            raise
        raise ModelError(f"{name} is not a readable .npz archive ({exc})") from None


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
    """Every dataset of a universal file as pyuff's dicts (needs the optional ``pyuff``): a file
    above :data:`UFF_BYTES_MAX`, cut inside a dataset (a first line ``-1`` without its last) or
    that pyuff cannot parse is refused naming it."""
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"uff: no such file {str(path)!r}")
    try:
        import pyuff
    except ImportError:
        raise ModelError("uff: reading UFF files needs pyuff: pip install 'modalctl[uff]'") from None
    _check_bytes(f"uff: {str(path)!r}", path.stat().st_size, UFF_BYTES_MAX)
    text = path.read_bytes()
    ends = [m.end() for m in UFF_DELIMITER.finditer(text)]
    if len(ends) % 2 or (ends and text[ends[-1]:].strip()):
        raise ModelError(f"uff: {str(path)!r} is cut inside a dataset or holds text after the last one (each "
                         "opens and closes with a line -1): truncated or damaged")
    try:
        sets = pyuff.UFF(str(path)).read_sets() if ends else []
    except Exception as exc:  # noqa: BLE001 (pyuff raises Exception itself for a damaged dataset)
        raise ModelError(f"uff: {str(path)!r} cannot be read: {exc}") from None
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
