"""Public measured FRF sets converted to universal files (UFF 58 + 15), as a lab would export them.

The data are not kept in this repository (a few MB each): fetch each source's repository and
point this script at the folder named below; nothing is fetched here, nor at test time. Each
set is written as it was measured, with its 0 Hz bin, its units and its directions, so that
``modalctl identify --frf`` meets what a new user meets.

Sets (``SETS``; their published modal parameters are in ``benchmarks/identify_real.py``):

``modelab-beam``
    alxhslm/ModeLAB, folder ``Example/SignalCalc``: a roving-hammer test of a free-free beam,
    nine hammer points along it (``setup.csv``), one accelerometer along -x at 0.5 m, accelerance
    (m/s^2/N) exported by DataPhysics SignalCalc from 0 to 1000 Hz every 0.0195 Hz, no coherence.
    Written as measured: nine references, one response (a roving hammer: read by reciprocity).
``tool-tip``
    leekunhwee/Vibration-Signal-Processing, folder ``ExperimentalModalAnalysis``: an impact test
    of a cutting tool in its holder, receptance H_1k (m/N) between the tip (point 1) and five
    points at 0, 55, 90, 130 and 165 mm from it (``Proj_3.m``), 0 to 5000 Hz every 1 Hz.

Usage::

    python benchmarks/real_data/convert.py modelab-beam PATH/TO/ModeLAB/Example/SignalCalc OUT.uff
    python benchmarks/real_data/convert.py tool-tip PATH/TO/ExperimentalModalAnalysis OUT.uff
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np


def read_signalcalc(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """A DataPhysics SignalCalc ASCII export: header lines, then ``Hz  real  imaginary``;
    returns frequencies (Hz) and the complex function."""
    rows = []
    for line in path.read_text(encoding="latin-1").splitlines():
        parts = line.split()
        try:
            rows.append([float(p) for p in parts[:3]])
        except ValueError:
            continue
    table = np.array([r for r in rows if len(r) == 3])
    return table[:, 0], table[:, 1] + 1j * table[:, 2]


def read_setup(path: Path) -> dict[str, list[float]]:
    """ModeLAB's ``setup.csv``: one row per quantity, its values across."""
    with path.open(newline="") as handle:
        return {row[0]: [float(v) for v in row[1:] if v.strip()] for row in csv.reader(handle) if row}


def write_uff(out: Path, nodes: dict[int, tuple[float, float, float]], functions: list[dict]) -> Path:
    """Dataset 15 (``nodes``: number -> x, y, z in m) then one dataset 58 per function (the
    keywords of ``pyuff.prepare_58``), an FRF against frequency."""
    import pyuff

    out.parent.mkdir(parents=True, exist_ok=True)
    if out.exists():
        out.unlink()
    uff = pyuff.UFF(str(out))
    numbers = sorted(nodes)
    xyz = np.array([nodes[n] for n in numbers], float)
    uff.write_sets(pyuff.prepare_15(node_nums=numbers, def_cs=[0] * len(numbers), disp_cs=[0] * len(numbers),
                                    color=[0] * len(numbers), x=xyz[:, 0], y=xyz[:, 1], z=xyz[:, 2]), mode="add")
    for f in functions:
        uff.write_sets(pyuff.prepare_58(func_type=4, abscissa_spacing=1, abscissa_spec_data_type=18, binary=0,
                                        **f), mode="add")
    return out


def modelab_beam(folder: Path, out: Path) -> Path:
    """ModeLAB's example: nine SignalCalc runs (hammer points, ``setup.csv`` order), one accelerometer."""
    setup = read_setup(folder / "setup.csv")
    runs = sorted(folder.glob("ASCII*/Hxysv*.txt"))
    hammer_z, accel_z = setup["zHammer"], setup["zAccel"][0]
    if len(runs) != len(hammer_z):
        raise SystemExit(f"{folder}: {len(runs)} runs for {len(hammer_z)} hammer points in setup.csv")
    nodes = {i + 1: (0.0, 0.0, z) for i, z in enumerate(hammer_z)}
    sensor = next((n for n, p in nodes.items() if abs(p[2] - accel_z) < 1e-9), None)
    if sensor is None:
        sensor = 100
        nodes[sensor] = (0.0, 0.0, accel_z)
    functions = []
    for i, run in enumerate(runs):
        freqs, h = read_signalcalc(run)
        functions.append(dict(rsp_node=sensor, rsp_dir=-1, ref_node=i + 1, ref_dir=1, data=h, x=freqs,
                              id1=f"{run.parent.name} hammer {i + 1} accel {sensor}", rsp_ent_name="beam",
                              ref_ent_name="beam", ordinate_spec_data_type=12, orddenom_spec_data_type=13,
                              ordinate_axis_units_lab="m/s^2", orddenom_axis_units_lab="N"))
    return write_uff(out, nodes, functions)


TOOL_POINTS_M = [0.0, 0.055, 0.090, 0.130, 0.165]  # Proj_3.m: y = [0 55 90 130 165] (mm), point 1 the tip


def tool_tip(folder: Path, out: Path) -> Path:
    """The tool's five receptances H_1k (tab-separated ``Hz real imaginary``, m/N)."""
    nodes = {k + 1: (0.0, y, 0.0) for k, y in enumerate(TOOL_POINTS_M)}
    functions = []
    for k in range(len(TOOL_POINTS_M)):
        table = np.loadtxt(folder / f"Point_{k + 1}_Channel_1_CH1.txt")
        functions.append(dict(rsp_node=1, rsp_dir=3, ref_node=k + 1, ref_dir=3, data=table[:, 1] + 1j * table[:, 2],
                              x=table[:, 0], id1=f"H1{k + 1}", rsp_ent_name="tool", ref_ent_name="tool",
                              ordinate_spec_data_type=8, orddenom_spec_data_type=13,
                              ordinate_axis_units_lab="m", orddenom_axis_units_lab="N"))
    return write_uff(out, nodes, functions)


SETS = {"modelab-beam": modelab_beam, "tool-tip": tool_tip}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("set", choices=sorted(SETS))
    parser.add_argument("source", type=Path, help="the folder of the fetched repository named in the docstring")
    parser.add_argument("out", type=Path, help="universal file to write")
    args = parser.parse_args(argv)
    if not args.source.is_dir():
        print(f"convert: no folder {args.source}", file=sys.stderr)
        return 2
    print(SETS[args.set](args.source, args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
