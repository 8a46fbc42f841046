"""Start-up: what importing modalctl and asking the command line for help cost, beside a bare python.

    python benchmarks/startup.py

writes benchmarks/results/startup.{json,md}. Each command runs in a fresh process ``REPEATS`` times
(median); the peer is ``python -c pass`` in the same run, so the ratio and the difference say what
modalctl adds. Targets (issue 35): ``import modalctl`` and ``modalctl --help`` within 0.5 s.
"""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
from common import command_line, write_json, write_markdown

REPEATS = 7
TARGET_S = 0.5
COMMANDS = {
    "python -c pass (the peer)": [sys.executable, "-c", "pass"],
    "import modalctl": [sys.executable, "-c", "import modalctl"],
    "modalctl --help": [sys.executable, "-c", "import sys; from modalctl.cli import main; sys.exit(main(['--help']))"],
    "modalctl run --help": [sys.executable, "-c",
                            "import sys; from modalctl.cli import main; sys.exit(main(['run', '--help']))"],
    "import modalctl.api (the front door)": [sys.executable, "-c", "import modalctl.api"],
}


def wall(command: list[str]) -> float:
    start = time.perf_counter()
    subprocess.run(command, check=False, capture_output=True)
    return time.perf_counter() - start


def main() -> None:
    for command in COMMANDS.values():  # warm the file cache: the first run reads the files from disk
        wall(command)
    rows = {name: float(np.median([wall(command) for _ in range(REPEATS)])) for name, command in COMMANDS.items()}
    bare = rows["python -c pass (the peer)"]
    path = write_json("startup", {"median_s": rows, "repeats": REPEATS, "target_s": TARGET_S})
    lines = ["# Start-up", "", f"`python benchmarks/startup.py`: median of {REPEATS} fresh processes each, beside "
             "`python -c pass` in the same run.", "", "| command | median s | over python -c pass s | target |",
             "|---|---|---|---|"]
    for name, seconds in rows.items():
        target = "" if "import modalctl" != name and "modalctl --help" != name else (
            f"<= {TARGET_S:g} s: {'met' if seconds <= TARGET_S else 'NOT met'}")
        lines.append(f"| {name} | {seconds:.3f} | {seconds - bare:+.3f} | {target} |")
    write_markdown("startup", lines, path)


if __name__ == "__main__":
    command_line()
    main()
