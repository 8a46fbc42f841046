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
``strip``
    WangSuhan/Modal-identification-of-plate, folder ``20201016``: a roving-hammer test of a
    free-free steel strip (1.252 m by 0.165 m, ``beam.png``): hammer points 1 to 10 every 0.1 m
    along its centre line, two accelerometers, at points 1 and 5; file ``20201016_AA_HH.mat`` is
    the FRF of the accelerometer at point AA to the hammer at point HH, 0 to 1024 Hz every 0.5 Hz
    (exported by the analyzer as ``MAT_001_FRF_Channel_8``: frequency, then the complex FRF, an
    accelerance by its rise with frequency; the files do not give the unit: m/s^2/N assumed).
    Written as measured: ten references, two responses.
``rail-wheel``
    virgilecheminot/ADMS-Assignments, file ``Assignment 1/LRV_wheel_FRF.mat`` (Politecnico di
    Milano's Advanced Dynamics of Mechanical Systems course data): an impact test of a light rail
    vehicle's resilient wheel, free-free, one axial hammer point, twelve accelerometers sensing the
    rim's axial vibration every 15 degrees over half the wheel; inertance 0 to 5000 Hz every
    1/3 Hz with its coherence. The rim's radius is not given: 0.3 m is assumed (it scales the
    geometry only); the hammer's place is not given either, so its node has no coordinates.
    Written with the coherence (function type 6) beside each FRF.
``liege-aircraft``
    Renkinios/MECA0062-1_vibration_testing (University of Liège, MECA0062 Vibration Testing and
    Experimental Modal Analysis, 2024), folder ``data``: a roving-hammer test of a free aluminium
    aircraft model (fuselage box, 1.5 m wing, tails, two engine masses), 74 hammer points
    (``node_shock.csv``, mm), three fixed accelerometers; ``sec_lab/DPsvNNNNN.mat`` are DataPhysics
    SignalCalc MAT exports, ``H1_k`` the accelerance (g/N) of accelerometer k (channels 2-4) to the
    hammer (channel 1), 0 to 200 Hz every 0.125 Hz, ``C1_k`` its coherence. Files 1-28, 31-58 and
    61-78 are the hammer points in ``node_shock.csv``'s order (``src/PullData.py``,
    ``extract_H_general``, and ``src/main.py``): the 56 wing points and 12 horizontal-tail points hit
    along z, the vertical tail's 6 along x (``src/VizMode.py``); files 29, 30, 59, 60 are hits the
    author does not use (no coordinates), file 0 repeats file 78. The 68 points hit along z are written
    (a shape is one component of the motion: modalctl refuses points along several axes, and the fin's
    six, hit along x, are left out) with the three accelerometers as three responses, nodes 1000-1002
    without coordinates (their places are not given; the other team's code, QUICKguils/vibtest, puts
    them at the wing tip, the horizontal tail's tip, along z, and the fin's tip, along x): read by
    reciprocity, three inputs, along any axis. g/N converted to m/s^2/N (g = 9.80665); written with
    the coherence. The points are written onto the wing's plane (``aircraft_plane``): modalctl refuses
    points that lie on neither a line nor a plane, as the measured ones do (the tail 75 mm above).

Usage::

    python benchmarks/real_data/convert.py modelab-beam PATH/TO/ModeLAB/Example/SignalCalc OUT.uff
    python benchmarks/real_data/convert.py tool-tip PATH/TO/ExperimentalModalAnalysis OUT.uff
    python benchmarks/real_data/convert.py strip PATH/TO/Modal-identification-of-plate/20201016 OUT.uff
    python benchmarks/real_data/convert.py rail-wheel "PATH/TO/ADMS-Assignments/Assignment 1" OUT.uff
    python benchmarks/real_data/convert.py liege-aircraft PATH/TO/MECA0062-1_vibration_testing/data OUT.uff
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
    keywords of ``pyuff.prepare_58``), against frequency: an FRF unless ``func_type`` says else."""
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
        f = {"func_type": 4, **f}
        uff.write_sets(pyuff.prepare_58(abscissa_spacing=1, abscissa_spec_data_type=18, binary=0, **f), mode="add")
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


STRIP_POINTS_M = [0.094 + 0.1 * k for k in range(11)]  # beam.png: point 0 at 9.4 cm from the right end
STRIP_SENSORS = (1, 5)  # beam.png: the accelerometers (red)


def read_analyzer_mat(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """A MATLAB file of one exported FRF: one variable, columns frequency (Hz) and the complex FRF."""
    from scipy.io import loadmat

    table = [v for k, v in loadmat(path).items() if not k.startswith("__")]
    if len(table) != 1 or table[0].ndim != 2 or table[0].shape[1] != 2:
        raise SystemExit(f"{path}: one (n, 2) table of frequency and FRF expected")
    return table[0][:, 0].real, table[0][:, 1]


def strip(folder: Path, out: Path) -> Path:
    """The strip's twenty FRFs: accelerometers at points 1 and 5, the hammer at points 1 to 10."""
    nodes = {k: (x, 0.0, 0.0) for k, x in enumerate(STRIP_POINTS_M)}
    functions = []
    for sensor in STRIP_SENSORS:
        for hammer in range(1, 11):
            freqs, h = read_analyzer_mat(folder / f"20201016_{sensor:02d}_{hammer:02d}.mat")
            functions.append(dict(rsp_node=sensor, rsp_dir=3, ref_node=hammer, ref_dir=3, data=h, x=freqs,
                                  id1=f"accelerometer {sensor} hammer {hammer}", rsp_ent_name="strip",
                                  ref_ent_name="strip", ordinate_spec_data_type=12, orddenom_spec_data_type=13,
                                  ordinate_axis_units_lab="m/s^2", orddenom_axis_units_lab="N"))
    return write_uff(out, {k: nodes[k] for k in range(1, 11)}, functions)


WHEEL_RADIUS_M = 0.3  # not given by the source: scales the geometry only
WHEEL_HAMMER = 100  # the hammer's node (its place is not given)


def rail_wheel(folder: Path, out: Path) -> Path:
    """The wheel's twelve inertances and coherences, accelerometers every 15 degrees on the rim."""
    from scipy.io import loadmat

    data = loadmat(folder / "LRV_wheel_FRF.mat")
    freqs, frf, coherence = data["freq"][:, 0], data["frf"].T, data["cohe"].T
    angles = np.radians(15.0 * np.arange(frf.shape[0]))
    nodes = {k + 1: (WHEEL_RADIUS_M * np.cos(a), WHEEL_RADIUS_M * np.sin(a), 0.0) for k, a in enumerate(angles)}
    functions = []
    for k in range(frf.shape[0]):
        common = dict(rsp_node=k + 1, rsp_dir=3, ref_node=WHEEL_HAMMER, ref_dir=3, x=freqs, rsp_ent_name="wheel",
                      ref_ent_name="wheel")
        functions.append(dict(common, data=frf[k], id1=f"inertance {k + 1}", ordinate_spec_data_type=12,
                              orddenom_spec_data_type=13, ordinate_axis_units_lab="m/s^2",
                              orddenom_axis_units_lab="N"))
        functions.append(dict(common, func_type=6, data=coherence[k], id1=f"coherence {k + 1}",
                              ordinate_spec_data_type=0, orddenom_spec_data_type=0))
    return write_uff(out, nodes, functions)


G = 9.80665  # m/s^2 per g
AIRCRAFT_FILES = [*range(1, 29), *range(31, 59), *range(61, 79)]  # node_shock.csv's rows, in order
AIRCRAFT_Z_POINTS = 68  # the wing's and the horizontal tail's points, hit along z, first; the fin's 6 along x
AIRCRAFT_ACCELEROMETERS = {2: (1000, 3), 3: (1001, 3), 4: (1002, 1)}  # H1_k -> its node and direction


def aircraft_plane(xyz: list[float]) -> tuple[float, float, float]:
    """A hammer point (m) of the wing or the horizontal tail laid on the wing's plane, z = 0: modalctl
    takes points on a line or a plane, and refuses the measured 3-D layout ('the measured nodes do not
    lie on a line or a plane'): the tail, 75 mm above the wing, keeps its x and y. Its shapes are read
    on these points; the frequencies and dampings do not depend on them."""
    x, y, _ = xyz
    return (x, y, 0.0)


def liege_aircraft(folder: Path, out: Path) -> Path:
    """The aircraft model's 68 hammer points along z (DataPhysics MAT exports), three accelerometers."""
    from scipy.io import loadmat

    with (folder / "node_shock.csv").open(newline="") as handle:
        rows = [[float(v) / 1000.0 for v in row] for row in list(csv.reader(handle))[1:] if row]
    if len(rows) != len(AIRCRAFT_FILES):
        raise SystemExit(f"{folder}: {len(rows)} hammer points in node_shock.csv for {len(AIRCRAFT_FILES)} files")
    nodes = {k + 1: aircraft_plane(xyz) for k, xyz in enumerate(rows[:AIRCRAFT_Z_POINTS])}
    functions = []
    for sensor, (node, direction) in AIRCRAFT_ACCELEROMETERS.items():
        for k, number in enumerate(AIRCRAFT_FILES[:AIRCRAFT_Z_POINTS]):
            data = loadmat(folder / "sec_lab" / f"DPsv{number:05d}.mat")
            frf, coherence = data[f"H1_{sensor}"], data[f"C1_{sensor}"]
            common = dict(rsp_node=node, rsp_dir=direction, ref_node=k + 1, ref_dir=3,
                          x=frf[:, 0].real, rsp_ent_name="aircraft", ref_ent_name="aircraft")
            functions.append(dict(common, data=frf[:, 1] * G, id1=f"DPsv{number:05d} H1_{sensor}",
                                  ordinate_spec_data_type=12, orddenom_spec_data_type=13,
                                  ordinate_axis_units_lab="m/s^2", orddenom_axis_units_lab="N"))
            functions.append(dict(common, func_type=6, data=coherence[:, 1].real, id1=f"DPsv{number:05d} C1_{sensor}",
                                  ordinate_spec_data_type=0, orddenom_spec_data_type=0))
    return write_uff(out, nodes, functions)


SETS = {"modelab-beam": modelab_beam, "tool-tip": tool_tip, "strip": strip, "rail-wheel": rail_wheel,
        "liege-aircraft": liege_aircraft}


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
