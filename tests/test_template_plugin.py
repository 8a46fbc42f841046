"""The template device plugin installs, registers its scheme by entry point and runs against the emulator."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

TEMPLATE = Path(__file__).resolve().parents[1] / "templates" / "device-plugin"


@pytest.mark.slow
def test_template_plugin_installs_and_passes_its_own_tests(tmp_path):
    target = tmp_path / "site"
    install = subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps",
                              "--target", str(target), str(TEMPLATE)], capture_output=True, text=True)
    assert install.returncode == 0, install.stderr
    assert any(p.name.startswith("modalctl_myboard") for p in target.iterdir())
    env = {**os.environ, "PYTHONPATH": str(target)}
    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(TEMPLATE / "tests")],
                         capture_output=True, text=True, env=env, cwd=tmp_path)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "2 passed" in run.stdout
