"""The folder a command writes its results into (``--out``): one run per folder, every file
replaced atomically, no link followed out of it.

:func:`claim` takes a folder for a run: it makes it, refuses one that holds another run (a
different command or options, said in its ``run.json``) unless forced, and removes the previous
run's files first, so that a run that fails half-way never leaves an older run's results beside its
own. :func:`atomic` writes one file: into a temporary name in the same folder, then renamed over
the final name, so that a reader sees the old file or the new one, never half of one, and a link
planted under that name is replaced, never followed; a write the disk refuses (full, read-only)
is an :class:`OutDirError` naming the file. :func:`check_writable` refuses, before any work, a path
results cannot be written to: a device, the kernel's files (``/proc``, ``/sys``), a read-only or
unwritable folder, a file where a folder is needed. A foundation module: it imports nothing of
modalctl but :mod:`modalctl.errors`.
"""

from __future__ import annotations

import json
import os
import re
import secrets
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from modalctl.errors import InputError

__all__ = ["OutDirError", "claim", "record", "atomic", "check_writable", "MANIFEST", "CLAIMED"]

MANIFEST = "run.json"  # which command and options made the folder's results
RESULTS = ("metrics.json", "fields.npz", "refusal.json", "log.json", "log.bin", "log-learning.json", "log-learning.bin",
           "sweep.json", "sweep.md")


#: Every folder :func:`claim` took in this process, in order: where a command that fails after
#: claiming its folder writes why (the command line's internal errors, ``modalctl.cli.common``).
CLAIMED: list[Path] = []

TEMPORARY_EXTRA = 14  # what atomic's temporary name adds to the name it stands for: '.', '.1234abcd', '.tmp'
#: Filesystems of the kernel's state and of devices: no result is written there.
NOT_FOR_RESULTS = {"proc", "sysfs", "devtmpfs", "devpts", "cgroup", "cgroup2", "debugfs", "tracefs", "securityfs",
                   "configfs", "pstore", "bpf", "mqueue", "efivarfs", "binfmt_misc", "fusectl", "autofs", "hugetlbfs"}


class OutDirError(InputError):
    """The folder cannot take this run (another run's results in it, a file in its place), or a
    file of it cannot be written."""


def check_writable(path, folder: bool) -> None:
    """Refuse ``path`` as where results go (a ``folder`` to make, or a file to write), before any
    work: a file where a folder is needed or the reverse, a device or another special file, a
    path through a file, the kernel's filesystems (:data:`NOT_FOR_RESULTS`), a read-only mount, a
    folder this user cannot write into.

    Raises
    ------
    OutDirError
        Saying which part of ``path`` is the matter.
    """
    path = Path.cwd() / path  # not normalized: 'new/..' is what the kernel makes of it, not what the text says
    try:
        _check_writable(path, folder)
    except OSError as exc:  # a name too long, a loop of links: what the system says of it
        raise OutDirError(f"{str(path)!r}: {exc.strerror or exc}") from None


def _check_writable(path: Path, folder: bool) -> None:
    for i, part in enumerate(path.parts):
        if part == ".." and not Path(*path.parts[:i]).is_dir():
            raise OutDirError(f"{str(path)!r} goes up ('..') from {str(Path(*path.parts[:i]))!r}, not an existing "
                              "directory")
    if path.exists():
        if folder and not path.is_dir():
            raise OutDirError(f"{str(path)!r} is a file, not a directory")
        if not folder and path.is_dir():
            raise OutDirError(f"{str(path)!r} is a directory; give a file name")
        if not folder and not path.is_file():
            raise OutDirError(f"{str(path)!r} is a device or another special file, not a file for results")
    near = path if folder else path.parent
    while not near.exists() and near != near.parent:
        near = near.parent
    if not near.is_dir():
        raise OutDirError(f"{str(path)!r} goes through {str(near)!r}, which is not a directory")
    most = os.pathconf(near, "PC_NAME_MAX")
    names = [(part, most) for part in path.parts[1:-1]] + [(path.name, most if folder else most - TEMPORARY_EXTRA)]
    longest = max(names, key=lambda named: len(os.fsencode(named[0])) - named[1])
    if len(os.fsencode(longest[0])) > longest[1]:
        raise OutDirError(f"{str(path)!r}: the name {longest[0][:40]!r}... is longer than the {longest[1]} bytes "
                          "this filesystem takes" + ("" if folder else " (with the temporary name's tail)"))
    kind, options = _filesystem(near)
    if kind in NOT_FOR_RESULTS:
        raise OutDirError(f"{str(path)!r} is on the kernel's {kind} filesystem, not a place for results")
    if "ro" in options:
        raise OutDirError(f"{str(path)!r} is on a read-only filesystem")
    if not os.access(near, os.W_OK | os.X_OK):
        raise OutDirError(f"{str(near)!r} is not writable by this user")


def _filesystem(path: Path) -> tuple[str, set[str]]:
    """The type and the mount options of the filesystem ``path`` is on (Linux's mount table; an
    empty type where there is none to read)."""
    where, found = os.path.realpath(path), ("", set())
    try:
        with open("/proc/self/mounts") as mounts:
            table = [line.split() for line in mounts]
    except OSError:
        return found
    longest = -1
    for fields in table:
        if len(fields) < 4:
            continue
        point = re.sub(r"\\([0-7]{3})", lambda m: chr(int(m.group(1), 8)), fields[1])  # \040: a space
        inside = where == point or where.startswith(point.rstrip("/") + "/")
        if inside and len(point) >= longest:  # the last mount on a point hides the earlier ones
            longest, found = len(point), (fields[2], set(fields[3].split(",")))
    return found


def claim(out: Path, command: str, options: dict, force: bool = False, defaults: dict | None = None) -> Path:
    """Make ``out`` the folder of one run of ``command`` with ``options`` (JSON-ready). An option one
    of the two runs does not record (a run made before the option existed) is taken at its value in
    ``defaults``.

    Raises
    ------
    OutDirError
        ``out`` holds the results of a different run (another command or other options) and
        ``force`` is False, or it holds results without a manifest.
    """
    out = Path(out)  # a folder's path: the CLI's --out type has refused a file already
    out.mkdir(parents=True, exist_ok=True)
    this = {"command": command, "options": _jsonable(options)}
    previous = _manifest(out)
    left = [name for name in RESULTS if (out / name).is_symlink() or (out / name).exists()]
    if previous is None and left and not force:
        raise OutDirError(f"out: {str(out)!r} holds results ({', '.join(left)}) of an unknown run; "
                          "--force replaces them, or give another --out")
    if previous is not None and not _same(previous.get("run"), this, _jsonable(defaults or {})) and not force:
        raise OutDirError(f"out: {str(out)!r} holds another run ({_describe(previous.get('run'), this)}); "
                          "--force replaces it, or give another --out")
    for name in [*left, *(previous or {}).get("files", [])]:
        _remove(out, name)
    with atomic(out / MANIFEST) as path:
        path.write_text(json.dumps({"run": this, "files": []}, indent=1))
    CLAIMED.append(out)
    return out


def record(out: Path, names: list[str]) -> None:
    """Add ``names`` (files of ``out``) to its manifest: what a later claim removes."""
    manifest = _manifest(out) or {"run": None, "files": []}
    manifest["files"] = sorted(set(manifest.get("files", [])) | set(names))
    with atomic(out / MANIFEST) as path:
        path.write_text(json.dumps(manifest, indent=1))


@contextmanager
def atomic(path: Path) -> Iterator[Path]:
    """A temporary path beside ``path`` (same suffix) to write; renamed over ``path`` when the block
    ends without an exception, removed otherwise."""
    path = Path(path)
    temporary = path.with_name(f".{path.stem}.{secrets.token_hex(4)}.tmp{path.suffix}")
    try:
        yield temporary
        os.replace(temporary, path)  # replaces a link of that name; never writes through it
    except OSError as exc:  # a full disk, a folder made read-only: the file that was there is left whole
        raise OutDirError(f"cannot write {str(path)!r}: {exc.strerror or exc}") from exc
    finally:
        if temporary.exists() or temporary.is_symlink():
            temporary.unlink()


def _manifest(out: Path) -> dict | None:
    path = out / MANIFEST
    if path.is_symlink() or not path.is_file():
        return None
    try:
        found = json.loads(path.read_text())
    except (ValueError, OSError, UnicodeDecodeError, RecursionError):
        return None
    return found if isinstance(found, dict) else None


def _remove(out: Path, name: str) -> None:
    """Remove ``out/name`` if it is a file or a link in ``out`` itself (nothing else is touched)."""
    path = out / name
    if Path(name).name != name or not (path.is_symlink() or path.is_file()):
        return
    path.unlink()


def _jsonable(options: dict) -> dict:
    return json.loads(json.dumps(options, default=str))


def _same(previous, this: dict, defaults: dict) -> bool:
    """Whether a manifest's run is ``this`` run, an option missing on one side taken at its default."""
    if not isinstance(previous, dict) or previous.get("command") != this["command"]:
        return False
    old, new = previous.get("options") or {}, this["options"]
    return all(old.get(k, defaults.get(k)) == new.get(k, defaults.get(k)) for k in set(old) | set(new))


def _describe(previous, this: dict) -> str:
    """What differs between two runs' manifests, briefly."""
    if not isinstance(previous, dict):
        return "unreadable manifest"
    if previous.get("command") != this["command"]:
        return f"modalctl {previous.get('command')}"
    old, new = previous.get("options") or {}, this["options"]
    changed = sorted(k for k in set(old) | set(new) if old.get(k) != new.get(k))
    return "other " + ", ".join(f"--{k.replace('_', '-')}" for k in changed[:4]) + (" ..." if len(changed) > 4 else "")
