"""Every command block of README.md (and docs/) runs (issue 39 item 1), against ``sim://`` or the emulators, in
a fresh folder, and ends as the README says; where the text quotes a number that does not move
(a mode count, a record's size, a tau or a voltage to the digits printed), it is checked. A changed
default that breaks a documented flow fails here, and so does a command the README adds or
changes without a line below: each README command must be named in :data:`HOW`.

What a block cannot run as written is said beside it: ``make`` targets (the demo's commands are
run from the Makefile by :func:`test_make_demo_s_commands_run`; ``make test`` is this suite and
``make bench`` the benchmarks' hour). Optional options ``[...]`` are dropped, or kept with their first choice where the block
is the README's list of what a command takes (``first``).
"""

from __future__ import annotations

import json
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from modalctl.cli import main

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
BIN = ".venv/bin/"


def readme_blocks() -> list[list[str]]:
    """The ``sh`` blocks of the README and of docs/, each a list of its commands: continuation
    lines joined, comments dropped, whitespace collapsed."""
    blocks = []
    text = "\n".join(page.read_text() for page in [README, *sorted((ROOT / "docs").glob("*.md"))])
    for block in re.findall(r"^```sh\n(.*?)^```", text, flags=re.M | re.S):
        commands = []
        for line in re.sub(r"\\\n\s*", " ", block).splitlines():
            line = re.sub(r"\s+#.*$", "", line).strip()
            if line and not line.startswith("#"):
                commands.append(" ".join(line.split()))
        blocks.append(commands)
    return blocks


def _metrics(folder: Path) -> dict:
    return json.loads((folder / "metrics.json").read_text())


def _serial_shot(out: str, *quoted: str) -> None:
    """The README's shots over the serial emulator: the default (convex) plan, what the text quotes."""
    assert "(convex planner)" in out, out
    for words in quoted:
        assert words in out, out
    assert float(re.search(r"margin ratio (\S+) measured", out).group(1)) <= 0.51, out  # 'at its edge' at 1.8 kHz


def _scenes(tmp: Path, out: str) -> None:
    for name in ("thesis-al-cc", "thesis-rython-pp", "thesis-al-ff", "plate-glass", "plate-glass-clamped",
                 "panel-rounded"):
        assert name in out


def _grown_panel(tmp: Path, out: str) -> None:
    """'a 30 mm bump on panel-rounded grows it from 22 modes below 11.8 kHz to 53 below 25 kHz (tau 0.980)'."""
    metrics = _metrics(tmp / "open")
    grown = metrics["model"]["grown"]
    assert grown["from_modes"] == 22 and round(grown["from_band_hz"] / 100) == 118 and grown["modes"] == 53
    assert round(grown["band_hz"] / 1e3) == 25 and round(metrics["tau"], 3) == 0.980  # (25.1 kHz)


def _tablet(tmp: Path, out: str) -> None:
    """'255 modes on 49,671 dofs', and no twin modes noted (its patches lie off the mirror axes)."""
    assert "255 modes from" in out and "on 49671 dofs" in out and "note: the patches push" not in out


def _field_shape(tmp: Path, out: str) -> None:
    """'the measured field back, as measured (8591 points x 11659 instants)'."""
    assert out.strip().endswith("(8591, 11659)")


#: Each README command: how it runs (``drop`` or ``first`` for its optional options; a reason
#: to skip or to expect it to fail), and what of its output is checked.
HOW = {
    "make demo": ("skip", "make's demo target: its commands run in test_make_demo_s_commands_run"),
    "make test": ("skip", "make test runs this suite"),
    "make bench": ("skip", "the benchmarks: most of an hour on two cores"),
    "python tools/architecture.py": ("skip", "docs/architecture.md's: it rewrites docs/architecture.png, a tracked "
                                             "file; tests/test_architecture.py checks the layers it draws"),
    ".venv/bin/modalctl scenes": ("drop", _scenes),
    ".venv/bin/modalctl plugins": ("drop", None),
    ".venv/bin/modalctl decompose --scene thesis-al-cc --shape sinc --param width=18mm --param center=24mm "
    "[--modes auto|all|N] [--tau-target 0.98] [--nrmse-target 0.1] [--orthogonalize] [--json] [--plot f.png]":
        ("first", None),
    ".venv/bin/modalctl run --scene thesis-al-cc --shape sinc --param width=18mm --param center=24mm "
    "--focus-time 25ms [--planner convex|envelope] [--margin 0.5|none] [--robust-drift 1%] "
    "[--voltage-limit 100V|none] [--slew-limit 2e6V/s] [--plan-time 120s|none] [--drift 1%] [--damping-error 20%] "
    "[--snr 40] "
    "[--scan-repeats N] [--amplifier-bandwidth 500kHz] [--seed N] [--transport sim://] --out DIR [--force] [--json]":
        ("first", None),
    ".venv/bin/modalctl model fe --outline rect:120mm,70mm,r=8mm --hole rect:42mm,0,20mm,10mm,r=4mm "
    "--thickness 1mm --material glass --boundary clamped --patch=-47mm,-33mm,-29mm,-19mm "
    "--patch=-7mm,7mm,-29mm,-19mm --patch=33mm,47mm,-29mm,-19mm --patch=-47mm,-33mm,19mm,29mm "
    "--patch=-7mm,7mm,19mm,29mm --patch=33mm,47mm,19mm,29mm --sensor 0,0 [--modes 30 | --band 12kHz] "
    "[--tolerance 0.5%] [--spacing 1mm] [--damping 1%] --out panel.npz": ("first", None),
    ".venv/bin/modalctl run --model panel.npz --shape bump --param width=40mm --param center=-20mm,5mm "
    "--focus-time 25ms --out DIR": ("drop", None),
    ".venv/bin/modalctl model fe --outline rect:210mm,150mm,r=8mm --thickness 0.7mm --material glass "
    "--boundary clamped --patch=-85mm,-71mm,-57mm,-47mm --patch=-38mm,-24mm,-57mm,-47mm "
    "--patch=10mm,24mm,-57mm,-47mm --patch=59mm,73mm,-57mm,-47mm --patch=-76mm,-62mm,52mm,62mm "
    "--patch=-29mm,-15mm,52mm,62mm --patch=21mm,35mm,52mm,62mm --patch=72mm,86mm,52mm,62mm --sensor 0,0 "
    "--band 20kHz --out tablet.npz": ("drop", _tablet),
    ".venv/bin/modalctl run --scene panel-rounded --shape bump --param width=30mm --param center=-20mm,5mm "
    "--focus-time 25ms --out open": ("drop", _grown_panel),
    ".venv/bin/modalctl run ... --loop closed --drift 1% --snr 40 --out closed": ("drop", None),
    ".venv/bin/modalctl run ... --loop closed --drift 1% --snr 40 --finger 1Ns/m --controller touch --out touch":
        ("drop", None),
    ".venv/bin/python -c \"from modalctl.model.records import read_field_record as r; "
    "print(r('closed/fields.npz').field.shape)\"": ("drop", _field_shape),
    ".venv/bin/modalctl run --scene thesis-al-cc --shape sinc --param width=18mm --param center=24mm "
    "--focus-time 25ms --modes 9 --loop closed --drift 1% --damping-error 20% --snr 40 --out DIR": ("drop", None),
    ".venv/bin/modalctl identify --scene thesis-al-cc [--snr 40] [--f-low 100Hz --f-high 100kHz] "
    "[--resolution 4Hz] [--step 1mm] [--method sdof|auto|mdof|peaks] [--averages 2] --out beam.npz":
        ("drop", None),
    ".venv/bin/modalctl run --model beam.npz --truth thesis-al-cc --shape sinc --param width=18mm "
    "--param center=24mm --focus-time 25ms --out run/": ("drop", None),
    ".venv/bin/modalctl identify --scene plate-glass --f-low 500Hz --f-high 15kHz --step 5mm --method auto "
    "--out plate.npz": ("drop", None),
    ".venv/bin/modalctl run --model plate.npz --truth plate-glass --shape gaussian --param width=30mm "
    "--focus-time 25ms --out plate-run/": ("drop", None),
    ".venv/bin/modalctl identify --frf panel.uff --mass-per-area 2.5kg/m^2 --method auto --out panel.npz":
        ("drop", None),
    ".venv/bin/modalctl run --scene thesis-al-cc --shape sinc --param width=18mm --param center=24mm "
    "--focus-time 25ms --drift 1% --damping-error 20% --snr 40 --loop closed [--control-rate 20kHz] "
    "[--controller touch+cluster|touch|pi|lqg|cluster] [--voltage-limit 100V|none] [--slew-limit 2V/us] "
    "[--authority 2] [--latency N] "
    "--out DIR": ("first", None),
    ".venv/bin/modalctl emulate --scene thesis-al-cc --drift 1% --snr 40": ("emulate", None),
    ".venv/bin/modalctl run --scene thesis-al-cc --shape sinc --param width=18mm --param center=24mm "
    "--focus-time 25ms --sample-rate 500kHz --loop board --transport serial:///dev/pts/N --out DIR":
        ("drop", lambda tmp, out: _serial_shot(out, "tau 0.9696", "margin ratio 0.465 measured (met")),
    ".venv/bin/modalctl run --scene thesis-al-cc --shape sinc --param width=18mm --param center=24mm "
    "--focus-time 25ms --sample-rate 500kHz --loop closed --control-rate 2kHz --transport serial:///dev/pts/N "
    "--out DIR": ("drop", lambda tmp, out: _serial_shot(out, "note: control at 1824.82 Hz, not 2000: the link carries "
                                                       "1829 periods/s with 8 modes")),
    ".venv/bin/modalctl sweep --vary drift=0,1%,2%,3% --vary finger=0,0.1,0.3,1Ns/m --damping-error 20% "
    "[--methods open,closed,tracked,learned] [--controller touch+cluster|touch|pi|lqg|cluster] "
    "[--voltage-limit 70V|none] "
    "[--workers N | --scheduler tcp://host:8786] --out DIR": ("drop", None),
}
#: Blocks of the README run here (by their first command), the slow ones (seconds each) marked.
FAST = {".venv/bin/modalctl scenes"}


def _optional(command: str, how: str) -> str:
    """``[...]`` dropped, or kept with the first of its choices (``a|b``, ``x | y``)."""
    if how != "first":
        return re.sub(r"\s*\[[^\]]*\]", "", command)

    def first(match) -> str:
        inner = match.group(1).split(" | ")[0]
        return re.sub(r"(\S+?)\|\S+", r"\1", inner)
    return re.sub(r"\[([^\]]*)\]", first, command)


def _argv(command: str, how: str, base: list[str], index: int, pty: str | None) -> list[str]:
    """The command's words after ``modalctl``: ``...`` is the block's first run's options (its
    --out left out), ``DIR`` a folder of its own, ``N`` 2, the emulator's pty for ``/dev/pts/N``."""
    words = shlex.split(_optional(command, how).removeprefix(BIN + "modalctl "))
    if "..." in words:
        at = words.index("...")
        rest = [w for i, w in enumerate(base[1:]) if w != "--out" and (i == 0 or base[i] != "--out")]
        words = words[:at] + rest + words[at + 1:]
    swap = {"DIR": f"dir{index}", "N": "2"}
    return [swap.get(w, w.replace("/dev/pts/N", pty or "/dev/pts/N")) for w in words]


def _panel_uff(path: Path) -> None:
    """A measured plate's FRFs as a lab exports them (UFF 58, nodes in UFF 15): what the README's
    ``identify --frf panel.uff`` reads."""
    sys.path.insert(0, str(Path(__file__).parent))
    try:
        from test_uff import grid_points, mobility, write
    finally:
        sys.path.pop(0)
    points = grid_points()
    write(path, points, mobility(points))


def _run_block(commands: list[str], tmp: Path, capsys) -> None:
    base: list[str] = []
    emulator = None
    try:
        for index, command in enumerate(commands):
            assert command in HOW, f"a README command no line of tests/test_readme.py runs: {command!r}"
            how, check = HOW[command]
            if how == "skip":
                continue
            if command.startswith(BIN + "python"):
                code = shlex.split(command)[2]
                done = subprocess.run([sys.executable, "-c", code], cwd=tmp, capture_output=True, text=True,
                                      timeout=600)
                assert done.returncode == 0, done.stderr
                check(tmp, done.stdout)
                continue
            if how == "emulate":
                emulator = _emulate(_argv(command, how, base, index, None), tmp)
                continue
            argv = _argv(command, how, base, index, emulator and emulator[1])
            if "..." not in command and argv[0] == "run":
                base = argv
            if "panel.uff" in argv:
                _panel_uff(tmp / "panel.uff")
            if how == "xfail":
                assert main(argv) == 0, f"{command}: {capsys.readouterr().err}"  # fails today: see HOW
                continue
            try:
                code = main(argv)
            except SystemExit as exit_:
                code = exit_.code
            said = capsys.readouterr()
            assert code == 0, f"{command}\n{said.err[-2000:]}"
            if check is not None:
                check(tmp, said.out)
    finally:
        if emulator is not None:
            emulator[0].terminate()
            emulator[0].wait(10)


def _emulate(argv: list[str], tmp: Path):
    """``modalctl emulate`` as the README starts it, in its own process: (process, its pty)."""
    process = subprocess.Popen([sys.executable, "-m", "modalctl", *argv], cwd=tmp, stdout=subprocess.PIPE,
                               text=True)
    line = process.stdout.readline()
    found = re.search(r"/dev/pts/\d+", line)
    if found is None:
        process.terminate()
        process.wait(10)
        pytest.fail(f"modalctl emulate did not say its pty: {line!r}")
    return process, found.group(0)


def _block_params():
    params = []
    for commands in readme_blocks():
        marks = [] if commands[0] in FAST else [pytest.mark.slow]
        reasons = [HOW.get(c, ("", ""))[1] for c in commands if HOW.get(c, ("",))[0] == "xfail"]
        if reasons:
            marks.append(pytest.mark.xfail(strict=True, reason=reasons[0]))
        if all(HOW.get(c, ("",))[0] == "skip" for c in commands):
            marks.append(pytest.mark.skip(reason="; ".join(HOW[c][1] for c in commands)))
        params.append(pytest.param(commands, marks=marks, id=commands[0].removeprefix(BIN)[:40]))
    return params


def test_every_readme_command_is_named_here():
    commands = [c for block in readme_blocks() for c in block]
    assert len(commands) >= 20, "the README's blocks were not found"
    missing = [c for c in commands if c not in HOW]
    assert not missing, f"README commands this test does not run: {missing}"
    assert not set(HOW) - set(commands), f"lines for commands the README no longer has: {set(HOW) - set(commands)}"


@pytest.mark.parametrize("commands", _block_params())
def test_every_readme_block_runs(commands, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _run_block(commands, tmp_path, capsys)


@pytest.mark.slow
def test_make_demo_s_commands_run(tmp_path, capsys, monkeypatch):
    """The Makefile's demo, command by command; the closed loop's numbers as the README quotes them
    ('1% drift measures 0.489 (tau 0.970, 40 V; make demo's demo/closed)', read from the README)."""
    monkeypatch.chdir(tmp_path)
    recipe = (ROOT / "Makefile").read_text().split("\ndemo:", 1)[1].split("\n\n", 1)[0]
    lines = " ".join(re.sub(r"\\\n\s*", " ", recipe).splitlines()[1:])
    commands = [c.strip() for c in lines.split("$(BIN)/modalctl") if c.strip() and not c.strip().startswith("@")]
    commands = [c.split("@echo")[0].strip() for c in commands]
    assert len(commands) == 3
    for command in commands:
        assert main([*shlex.split(command), "--no-plots", "--quiet"]) == 0, capsys.readouterr().err
    closed = _metrics(tmp_path / "demo" / "closed")
    quoted = re.search(r"1% drift\s+measures (0\.\d+) \(tau (0\.\d+), (\d+) V; `make demo`'s `demo/closed`\)",
                       README.read_text())
    ratio, tau, volts = float(quoted.group(1)), float(quoted.group(2)), int(quoted.group(3))
    assert round(closed["tau"], 3) == tau and round(closed["margin_ratio"], 3) == ratio < 0.5
    assert round(closed["peak_voltage"]) == volts and closed["peak_voltage"] < closed["voltage_limit_v"]


def test_the_api_example_runs(capsys):
    code = re.search(r"^```python\n(.*?)^```", README.read_text(), flags=re.M | re.S).group(1)
    exec(compile(code, "README.md", "exec"), {})
    decomposed, shot = capsys.readouterr().out.strip().splitlines()[-2:]
    words = shot.replace("[", " ").replace("]", " ").replace(",", " ").split()  # tau, [crossovers], seconds
    assert 0.9 < float(decomposed) <= 1 and 0.9 < float(words[0]) <= 1 and float(words[-1]) > 0
    assert all(float(w) > 0 for w in words[1:-1])
