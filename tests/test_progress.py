"""Progress (issue 39): bars only on a terminal; a log or a pipe gets one line per stage, never the
bars' carriage-return frames."""

import fcntl
import os
import pty
import struct
import subprocess
import sys
from pathlib import Path

import pytest
import termios

ROOT = Path(__file__).resolve().parents[1]
SHOT = ["run", "--scene", "thesis-al-cc", "--points", "61", "--shape", "sinc", "--param", "width=18mm",
        "--focus-time", "25ms", "--loop", "closed", "--no-plots"]


def _modalctl(argv, stderr) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "modalctl", *argv], stdout=subprocess.DEVNULL, stderr=stderr,
                          env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=300)


@pytest.mark.slow
def test_a_shot_logged_to_a_file_has_one_line_per_stage_and_no_bar(tmp_path):
    with open(tmp_path / "log.txt", "wb") as log:
        assert _modalctl([*SHOT, "--out", str(tmp_path / "out")], log).returncode == 0
    text = (tmp_path / "log.txt").read_text()
    assert "\r" not in text
    assert [line.split(":")[1].split()[1] for line in text.splitlines()] == ["model", "shot", "report"]


@pytest.mark.slow
def test_a_shot_on_a_terminal_draws_its_bars(tmp_path):
    main, child = pty.openpty()
    fcntl.ioctl(child, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))  # a new terminal is 0 wide: no bar
    try:
        assert _modalctl([*SHOT, "--out", str(tmp_path / "out")], child).returncode == 0
        os.close(child)
        said = b""
        while True:
            try:
                chunk = os.read(main, 65536)
            except OSError:  # the terminal's other end closed: all was read
                break
            if not chunk:
                break
            said += chunk
    finally:
        os.close(main)
    assert b"closed loop" in said and b"\r" in said  # the loop's bar, drawn in place
    assert b"modalctl run: the shot" not in said  # no stage lines beside the bars


def test_quiet_says_nothing_on_stderr(tmp_path):
    with open(tmp_path / "log.txt", "wb") as log:
        assert _modalctl([*SHOT, "--quiet", "--out", str(tmp_path / "out")], log).returncode == 0
    assert (tmp_path / "log.txt").read_text() == ""
