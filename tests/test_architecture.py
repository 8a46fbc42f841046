"""The house keeps its shape: layers imported downward only, a small top level.

The layers and the other import rules are import-linter contracts in ``pyproject.toml``
(``[tool.importlinter]``); ``docs/architecture.md`` explains them.
"""

import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "modalctl"
LINT = [sys.executable, "-c", "import sys; from importlinter.cli import lint_imports_command; "
        "sys.exit(lint_imports_command())"]


def lint(cwd: Path, config: Path) -> subprocess.CompletedProcess:
    return subprocess.run([*LINT, "--no-logo", "--no-cache", str(config)], cwd=cwd, capture_output=True, text=True,
                          env={"PYTHONPATH": str(cwd), "PATH": ""})


def test_every_import_contract_of_the_layers_is_kept():
    """No module imports a layer above its own, the core imports no simulator, only report draws,
    only transports and emulators open ports."""
    run = lint(ROOT, ROOT / "pyproject.toml")
    assert run.returncode == 0, run.stdout + run.stderr
    assert "0 broken" in run.stdout


def test_the_layer_check_fails_on_an_upward_import(tmp_path):
    """The same check on a toy package whose low layer imports its high one: it must break."""
    package = tmp_path / "toy"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "high.py").write_text("from toy import low\n")
    (package / "low.py").write_text("def f():\n    from toy import high\n")  # upward, even inside a function
    config = tmp_path / "pyproject.toml"
    config.write_text(textwrap.dedent("""
        [tool.importlinter]
        root_package = "toy"
        [[tool.importlinter.contracts]]
        name = "layers"
        type = "layers"
        containers = ["toy"]
        layers = ["high", "low"]
    """))
    run = lint(tmp_path, config)
    assert run.returncode == 1, run.stdout + run.stderr
    assert "toy.low -> toy.high" in run.stdout


def test_the_top_level_holds_at_most_a_dozen_modules():
    modules = sorted(p.name for p in PACKAGE.glob("*.py"))
    assert len(modules) <= 12, modules
