"""The house keeps its shape: layers imported downward only, a small top level, narrow functions.

The layers and the other import rules are import-linter contracts in ``pyproject.toml``
(``[tool.importlinter]``); ``docs/architecture.md`` explains them.
"""

import ast
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


def wide_functions(path: Path, limit: int = 8) -> list[str]:
    """``name (count)`` of every function in ``path`` taking more than ``limit`` parameters (self and
    cls not counted; positional, keyword and keyword-only all counted)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            args = node.args
            names = [a.arg for a in args.posonlyargs + args.args + args.kwonlyargs if a.arg not in ("self", "cls")]
            if len(names) > limit:
                found.append(f"{node.name} ({len(names)})")
    return found


def test_no_function_takes_more_than_eight_parameters():
    """Options travel as dataclasses (modalctl.options), not as long parameter lists."""
    wide = [f"{path.relative_to(ROOT)}: {row}" for path in sorted(PACKAGE.rglob("*.py")) for row in wide_functions(path)]
    assert not wide, "\n".join(wide)


def test_the_parameter_count_sees_keyword_only_parameters_and_skips_self(tmp_path):
    source = tmp_path / "wide.py"
    source.write_text("def f(a, b, *, c, d, e, f, g, h, i):\n    pass\n\n"
                      "class A:\n    def g(self, a, b, c, d, e, f, g, h):\n        pass\n")
    assert wide_functions(source) == ["f (9)"]


def _contracts() -> list[dict]:
    import tomllib

    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]


def test_no_module_outside_the_hil_imports_it_and_the_command_line_imports_no_transport():
    """The contracts the layers test runs fence the simulator off every layer but its own (and the HIL
    benches that measure its truth), and the transports off the command line: the simulator is a
    plugin registered by entry point from inside hil/, reached by URL like any board."""
    from importlib.metadata import entry_points

    fenced = {source for c in _contracts() if "modalctl.hil" in c.get("forbidden_modules", [])
              for source in c["source_modules"]}
    top = {f"modalctl.{p.stem if p.is_file() else p.name}" for p in PACKAGE.iterdir()
           if (p.suffix == ".py" and p.stem != "__init__") or (p.is_dir() and (p / "__init__.py").exists())}
    benches = {"modalctl.experiments", "modalctl.hil"}
    assert top - benches <= fenced, sorted(top - benches - fenced)
    cli = [c for c in _contracts() if c.get("source_modules") == ["modalctl.cli"]]
    assert cli and {"modalctl.io.transports", "modalctl.hil"} <= set(cli[0]["forbidden_modules"])
    registered = {ep.value for ep in entry_points(group="modalctl")}
    assert "modalctl.hil.transport" in registered


def test_no_module_over_600_lines_and_no_function_over_80():
    """A reader takes a module in one sitting and a function in one screen (issue 35)."""
    long = []
    for path in sorted(PACKAGE.rglob("*.py")):
        text = path.read_text()
        if len(text.splitlines()) > 600:
            long.append(f"{path.relative_to(ROOT)}: {len(text.splitlines())} lines")
        long += [f"{path.relative_to(ROOT)}: {node.name} {node.end_lineno - node.lineno + 1} lines"
                 for node in ast.walk(ast.parse(text))
                 if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.end_lineno - node.lineno >= 80]
    assert not long, "\n".join(long)


def test_no_fft_spins_a_thread_pool_in_a_process_that_forks():
    """scipy.fft with ``workers`` other than 1 starts pocketfft's thread pool, which shuts itself down at
    every fork: a run forks its picture children back to back, and a CI worker that had measured FRFs
    with ``workers=-1`` earlier hung for good in that shutdown (gdb: fork -> pocketfft's prefork handler
    joining a pool thread that waits). No call in the package may ask for more than one worker."""
    calls = []
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and any(k.arg == "workers" for k in node.keywords):
                name = ast.unparse(node.func)
                if "fft" in name:
                    calls.append(f"{path.relative_to(ROOT)}:{node.lineno} {name}")
    assert not calls, calls
