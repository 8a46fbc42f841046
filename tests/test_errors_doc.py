"""docs/errors.md's examples, run: each command ends with its documented code and message, so the
page cannot drift from what the user sees."""

import re
import shlex
from pathlib import Path

import pytest

from modalctl.cli import main

PAGE = Path(__file__).resolve().parents[1] / "docs" / "errors.md"


def examples():
    """(command words, code, words of the message) of every row of the Examples table."""
    text = PAGE.read_text().split("## Examples", 1)[1]
    rows = re.findall(r"^\| `([^`]+)` \| (\d) \| (.+?) \|$", text, flags=re.M)
    assert len(rows) >= 10, "the examples table lost its rows"
    return [(shlex.split(command), int(code), words) for command, code, words in rows]


@pytest.mark.parametrize("argv, code, words", examples(), ids=lambda v: v if isinstance(v, int) else None)
def test_every_documented_refusal_ends_as_documented(tmp_path, capsys, argv, code, words):
    argv = [str(tmp_path / "out") if a == "OUT" else str(tmp_path / "missing.npz") if a == "MISSING" else a
            for a in argv]
    try:
        got = main([*argv, "--quiet"] if argv[0] == "run" else argv)
    except SystemExit as exit_:  # argparse's own refusals
        got = exit_.code
    assert got == code and words in capsys.readouterr().err
