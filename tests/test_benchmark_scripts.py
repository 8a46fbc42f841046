"""The benchmarks' command lines: every script parses its options, so ``--help`` says what it does
and a mistyped option is refused (exit 2) instead of starting the whole benchmark."""

import subprocess
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
SCRIPTS = sorted(p for p in BENCHMARKS.glob("*.py") if 'if __name__ == "__main__"' in p.read_text())


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_every_benchmark_parses_its_command_line(script):
    text = script.read_text()
    assert any(call in text for call in ("command_line(", "main_or_report(", "ArgumentParser(")), \
        f"{script.name} runs without parsing its options: --help or a typo would start the whole benchmark"


def test_help_and_a_mistyped_option_start_nothing():
    result = BENCHMARKS / "results" / "stability.json"
    before = result.stat().st_mtime_ns if result.exists() else None
    script = str(BENCHMARKS / "stability.py")
    helped = subprocess.run([sys.executable, script, "--help"], capture_output=True, text=True, timeout=120)
    assert helped.returncode == 0 and "Where a per-mode loop goes unstable" in helped.stdout
    typo = subprocess.run([sys.executable, script, "--reprot-only"], capture_output=True, text=True, timeout=120)
    assert typo.returncode == 2 and "unrecognized arguments: --reprot-only" in typo.stderr
    assert (result.stat().st_mtime_ns if result.exists() else None) == before  # nothing was run
