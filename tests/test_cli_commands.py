"""The command line's shape: one module per command, commands plugins add, and a start that loads
nothing numerical (issue 35)."""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

from modalctl.cli import build_parser, main
from modalctl.plugin.command import Command, plugin_commands

CLI = Path(__file__).resolve().parents[1] / "modalctl" / "cli"


def test_help_lists_the_commands_without_numpy_scipy_or_the_simulator():
    """``modalctl --help`` imports argparse and the command contract, not what the commands run on."""
    code = ("import sys\nfrom modalctl.cli import main\ntry:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
            "print(' '.join(sorted(sys.modules)), file=sys.stderr)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    loaded = set(done.stderr.split())
    assert "emulate" in done.stdout and "sweep" in done.stdout
    declared = {"modalctl.hil", "modalctl.hil.commands"}  # the HIL's command plugin declares emulate, lightly
    heavy = {m for m in loaded - declared if m.split(".")[0] in ("numpy", "scipy", "matplotlib")
             or m.startswith(("modalctl.hil", "modalctl.model", "modalctl.io", "modalctl.run", "modalctl.experiments"))}
    assert not heavy, f"modalctl --help loaded {sorted(heavy)}"


def test_the_command_line_imports_no_simulator_module():
    found = []
    for path in CLI.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            found += [f"{path.name}: {n}" for n in names if n.startswith("modalctl.hil")]
    assert not found


def test_emulate_is_the_hil_plugins_command():
    commands = plugin_commands()
    assert isinstance(commands["emulate"], Command)
    assert type(commands["emulate"]).__module__ == "modalctl.hil.commands"
    assert "--drift" in build_parser().commands["emulate"].format_help()  # the sim transport's options


def test_emulate_refuses_the_truth_of_another_structure(capsys):
    assert main(["emulate", "--truth", "plate-glass", "--for", "0.01s"]) == 2
    assert "--truth is for modalctl run" in capsys.readouterr().err


def test_the_sweep_takes_the_truth_as_the_simulator_declares_it_and_its_defaults_from_the_case():
    from modalctl.experiments.sweep import Case

    sweep = build_parser().commands["sweep"]
    case = Case()
    for dest, field in (("drift", "drift"), ("damping_error", "damping_error"), ("finger", "finger"),
                        ("snr", "snr_db"), ("seed", "seed"), ("focus_time", "focus_time"),
                        ("control_rate", "control_rate"), ("sample_rate", "sample_rate"), ("scene", "scene"),
                        ("shape", "shape"), ("planner", "planner"), ("controller", "controller")):
        assert sweep.get_default(dest) == getattr(case, field), dest
    with pytest.raises(SystemExit):
        sweep.parse_args(["--truth", "plate-glass", "--out", "x"])  # a case simulates its own scene


@pytest.mark.parametrize("path", sorted(CLI.glob("*.py")), ids=lambda p: p.name)
def test_no_command_module_is_long(path):
    tree = ast.parse(path.read_text())
    assert len(path.read_text().splitlines()) <= 600
    long = [f"{n.name}: {n.end_lineno - n.lineno + 1} lines" for n in ast.walk(tree)
            if isinstance(n, ast.FunctionDef) and n.end_lineno - n.lineno + 1 > 80]
    assert not long
