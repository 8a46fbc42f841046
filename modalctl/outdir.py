"""The folder a command writes its results into (``--out``): one run per folder, every file
replaced atomically, no link followed out of it.

:func:`claim` takes a folder for a run: it makes it, refuses one that holds another run (a
different command or options, said in its ``run.json``) unless forced, and removes the previous
run's files first, so that a run that fails half-way never leaves an older run's results beside its
own. :func:`atomic` writes one file: into a temporary name in the same folder, then renamed over
the final name, so that a reader sees the old file or the new one, never half of one, and a link
planted under that name is replaced, never followed. A foundation module: it imports nothing of
modalctl.
"""

from __future__ import annotations

import json
import os
import secrets
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

__all__ = ["OutDirError", "claim", "record", "atomic", "MANIFEST"]

MANIFEST = "run.json"  # which command and options made the folder's results
RESULTS = ("metrics.json", "fields.npz", "refusal.json", "log.json", "log.bin", "log-learning.json", "log-learning.bin",
           "sweep.json", "sweep.md")


class OutDirError(ValueError):
    """The folder cannot take this run (another run's results in it, a file in its place)."""


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
    finally:
        if temporary.exists() or temporary.is_symlink():
            temporary.unlink()


def _manifest(out: Path) -> dict | None:
    path = out / MANIFEST
    if path.is_symlink() or not path.is_file():
        return None
    try:
        found = json.loads(path.read_text())
    except (ValueError, OSError, UnicodeDecodeError):
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
