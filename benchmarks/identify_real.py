"""Identification on real measurements, read as the labs exported them, with default options, blind.

    python benchmarks/identify_real.py --data DIR     # DIR: the fetched sources (see below)
    python benchmarks/identify_real.py --report-only  # redraw from results/identify_real.json

writes benchmarks/results/identify_real.{json,md,png}. Needs pyuff and sdypy-EMA (``pip install
'modalctl[real-data]'``).

The data are public but not kept here (megabytes each, and under their owners' licences): fetch
each source's repository, and give ``--data`` a folder holding them as ``<data>/<name>.uff``
(converted already) or ``<data>/<repository folder>`` (converted here by
``benchmarks/real_data/convert.py``). Nothing is fetched by this script.

Each set is identified by ``modalctl identify --frf`` (:func:`identify_frf`, method ``auto``,
within the band a user reads off the file: above the suspension, below the analyzer's edge), and
by sdypy-EMA's LSCF (``pol_order_high`` 60) with the poles closest to the *published*
frequencies picked for it (its own picking is interactive: a head start modalctl does not get).
A published mode is *found* when a returned mode lies within 1% of it (and is not nearer another
published mode: one returned mode counts once); a returned mode farther
than 1% from every published one is *spurious*, unless the publication names a mode near it
without tabulating it (within 5%: the wheel's radial mode 'near 2100 Hz'). Shapes are compared
by MAC to the peer's (sdypy-EMA's normal modes) on the same points, of the input whose rows fit
best when there are several, and to the published shapes where there are some.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from common import RESULTS, machine, read_json, save_figure, write_json  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent / "real_data"))
import convert  # noqa: E402

from modalctl.identify.coarse import joint_pole, under_resolved  # noqa: E402
from modalctl.identify.estimators import constants_of  # noqa: E402
from modalctl.identify.frf import FRF  # noqa: E402
from modalctl.identify.survey import identify_frf, mac  # noqa: E402
from modalctl.identify.uff import read_uff58_references  # noqa: E402
from modalctl.model.modes import ModelError  # noqa: E402
from modalctl.model.projection import orthonormalize_model  # noqa: E402

NAME = "identify_real"
FOUND = 0.01  # a published mode is found within this relative distance
ROUND_OFF = 1e-13  # the relative change of a file's values the round-off check makes (far below any noise)
ROUND_OFF_DRAWS = 2  # seeded draws of that change
PEER_ORDER = 60

SETS = {
    "modelab-beam": {
        "title": "free-free beam, roving hammer (ModeLAB's example)",
        "source": "github.com/alxhslm/ModeLAB, Example/SignalCalc (GPL-3.0): DataPhysics SignalCalc export",
        "folder": "ModeLAB/Example/SignalCalc",
        "test": "9 hammer points along x, 1 accelerometer along -x; accelerance (m/s^2/N) 0-1000 Hz every "
                "0.0195 Hz, no coherence",
        "published_hz": [111.99, 306.86, 596.37, 974.14],
        "published_zeta": None,
        "published_by": "ModeLAB's README figure (Example/modeshapes.png), its peak-fit method",
        "band_hz": (65.0, 1000.0),  # setup.csv: fMin 65, fMax 1000
        "density": 1.0,  # kg/m, unknown: scales the shapes only
    },
    "tool-tip": {
        "title": "cutting tool in its holder, impact test (tip to 5 points)",
        "source": "github.com/leekunhwee/Vibration-Signal-Processing, ExperimentalModalAnalysis (no licence "
                  "stated): five exported FRFs",
        "folder": "Vibration-Signal-Processing/ExperimentalModalAnalysis",
        "test": "receptance H_1k (m/N), tip and 4 points up to 165 mm, 0-5000 Hz every 1 Hz, no coherence",
        "published_hz": [1074.0, 1961.0, 2617.0],
        "published_zeta": [0.034, 0.0454, 0.0453],
        "published_by": "its README: peaks of Im H11 and the extremes of Re H11 (half-power), read by hand; the "
                        "file's own H11 has its Im minima at 1071, 1981 and 2607 Hz (0.3%, 1.0%, 0.4% from the "
                        "values read), the other points' at 1057-1071, 1937-1981 Hz; Proj_3.m computes zeta3 from "
                        "mode 2's half-power points (0.034; the README's table gives 0.0453)",
        # README: the first three modal shapes p1, p2, p3 at the five points (tip first)
        "published_shapes": {1074.0: [1.4111, 0.9608, 0.6749, 0.4734, 0.3435],
                             1961.0: [1.7165, 0.7057, 0.1830, -0.1333, -0.2136],
                             2617.0: [2.0023, 0.4510, -0.1414, -0.2755, -0.3013]},
        "shape_points": "tool",
        "remarks": "The values were read by hand from H11 alone; the file's H11 has its Im minima at 1071, 1981 "
                   "and 2607 Hz, the other points' move by 14 Hz (mode 1) and 44 Hz (mode 2), so the reference "
                   "itself is uncertain by about 1%, ten times the 0.1% target. Band fits of this file (general "
                   "poles, all five FRFs): at 1000-1150 Hz one pole at 1073.8 Hz, zeta 0.034, leaves 4.5% (the "
                   "published 1074 Hz, 0.034); at 1700-2300 Hz one pole (1957.4 Hz, zeta 0.047) leaves 8.6%, two at "
                   "most 4.6%, three at most 2.4%; at 2400-2900 Hz one pole leaves 15.6%, two (near 2620 and "
                   "2750 Hz) at most 3.3%; the noise "
                   "is 0.05% of the largest |H|. The second and third regions hold more than one pole: 1961 and "
                   "2617 Hz are single-mode readings of them, not modes identifiable to 0.1% from this file. "
                   "298 Hz: every FRF's phase turns by 90 degrees between 280 and 320 Hz, a damped mode the "
                   "README does not read.",
        "band_hz": (100.0, 3500.0),  # Proj_3.m fits 101-3500 Hz
        "density": 1.0,
    },
    "strip": {
        "title": "free-free steel strip, roving hammer, two accelerometers",
        "source": "github.com/WangSuhan/Modal-identification-of-plate, 20201016 (no licence stated): 20 FRFs "
                  "exported by the analyzer as MATLAB files",
        "folder": "Modal-identification-of-plate/20201016",
        "test": "10 hammer points every 0.1 m along a 1.252 m strip, accelerometers at points 1 and 5; accelerance "
                "0-1024 Hz every 0.5 Hz, no coherence",
        # F.xlsx: the repository's own identification, one row per FRF; the mean of its ten rows
        # (their scatter: 0.05 to 0.3 Hz, 0.03% to 0.7%)
        "published_hz": [10.015, 27.002, 53.234, 87.951, 131.565, 184.323, 245.873, 315.981, 394.736, 481.690],
        "published_zeta": None,  # kesimd.xlsx and zetamd.xlsx disagree tenfold (0.2% and 3%), some negative
        "published_by": "the repository's identification results (F.xlsx, its 'difference method' fitted to each "
                        "FRF; mean of the ten rows, which scatter by 0.05-0.3 Hz); its damping tables disagree "
                        "tenfold and are not used",
        "remarks": "Lines every 0.5 Hz for a damping of 0.2-0.3%: below about 330 Hz a mode's half-power band "
                   "2 zeta f spans fewer than 3 lines (0.3-2.5), and modalctl fits such a pole once on all twenty "
                   "FRFs jointly, its frequency searched a twentieth of a line fine; the '+-' is that frequency's "
                   "jackknife standard error over the FRFs (the fit again with each left out): 0.15-0.29 Hz, "
                   "0.07-0.3% (3 sigma 0.2-0.9%), so the file fixes none of these modes to the 0.1% target, and "
                   "the published means "
                   "(of ten per-FRF fits that scatter by 0.05-0.3 Hz) are no closer: modalctl's and the peer's "
                   "values lie within 1.8 standard errors of them. 27 Hz: jointly 26.77 +- 0.14 Hz at a "
                   "damping of 1.2% (the others' 0.2%), one pole on each FRF alone anywhere in the line searched "
                   "either side; the FRFs' mean |H| (each input scaled to unit RMS) peaks only four to seven times "
                   "above its floor (0.15-0.27 at 15-25 Hz, 1.0 at 27 Hz): the mode is there, its frequency not "
                   "fixed within 1% (3 sigma), so it is left out and "
                   "says so (it was returned at 26.82 Hz, -0.69%, before: within this file's scatter, not a "
                   "fitting error). 10 Hz: jointly 10.03 +- 0.06 Hz (3 sigma 1.8%), the peer finds no pole there. "
                   "Shapes: the two accelerometers (points 1 and 5) give each mode's shape at the same ten "
                   "hammer points; below 200 Hz their shapes agree only to MAC 0.18-0.67 (last column; 0.92-0.99 "
                   "above 240 Hz), so a MAC of 0.99 to the peer is more than the file holds there: 53 Hz's 0.40 "
                   "is that disagreement (the peer's own two inputs' shapes agree to MAC 0.25-0.62 at 53-184 Hz), "
                   "184.3 Hz's 0.960 the "
                   "joint pole's (0.899 before: LSCF had put a pair of poles on the lines either side of the "
                   "peak, 183.98 and 184.54 Hz, and 183.98 Hz at zeta 0.0008 was kept; with today's numpy and "
                   "scipy LSCF puts none there, and the peak picker's half-power points come out the wrong way "
                   "round, the peak between two lines: that row is now fitted jointly too).",
        "band_hz": (5.0, 550.0),  # the published figure's span (README, 'Difference method fitting.png')
        "density": 1.0,
    },
    "rail-wheel": {
        "title": "light rail vehicle's resilient wheel, free-free, axial impact (PoliMi course data)",
        "source": "github.com/virgilecheminot/ADMS-Assignments, Assignment 1/LRV_wheel_FRF.mat (no licence stated; "
                  "Politecnico di Milano's Advanced Dynamics of Mechanical Systems data)",
        "folder": "ADMS-Assignments/Assignment 1",
        "test": "1 axial hammer point, 12 accelerometers every 15 degrees on half the rim; inertance 0-5000 Hz "
                "every 1/3 Hz, with coherence",
        "published_hz": [667.3, 1625.3, 2848.0, 4256.3],
        "published_zeta": [0.00751, 0.00554, 0.01756, 0.00371],
        "published_by": "Barutta, Meneghini, Milic, Visentin, 'Advanced Dynamics of Mechanical Systems, Assignment 1' "
                        "(PoliMi 2024, github.com/NicolaVisentin/Advanced_Dynamics), Table 3: a one-mode curve fit "
                        "per peak; they call mode 3 badly reconstructed (the wheel's mounting shifts some peaks) "
                        "and see a radial mode near 2100 Hz; modes 1-2 also by Cheminot, Kopec, Landolfo (2022, "
                        "the data's repository): 667.7 Hz (0.814%), 1624 Hz (0.599%), with shapes",
        "remarks": "2626, 3485-3496 and 3792 Hz lie on broad humps of the mean FRF (zeta 1.7-2%) where the "
                   "coherence stays 0.8-0.95, and 1333 Hz on a small one (the mean |H| 35% above its surroundings, "
                   "point 1's phase turning by 30 degrees, coherence 0.9); both publications tabulate the four major "
                   "peaks only, so these count as spurious here though the FRFs show them. Mode 3: the FRFs peak at two frequencies (2848 and "
                   "2858 Hz, the mounting the publication blames); its published damping (1.76%) is one pole "
                   "fitted over both.",
        "also_seen_hz": [2100.0],  # 'a small peak near 2100 Hz', a radial mode: named, not tabulated
        # Cheminot et al., Table 3: modal vectors at accelerometers 1-12 (0 to 165 degrees)
        "published_shapes": {667.3: [0.979, 0.894, 0.498, -0.027, -0.542, -0.908, -1.000, -0.866, -0.502, 0.033,
                                     0.521, 0.895],
                             1625.3: [-0.952, -0.676, 0.077, 0.748, 1.000, 0.692, -0.044, -0.746, -0.995, -0.660,
                                      0.069, 0.735]},
        "shape_points": "wheel",  # accelerometer k at 15 k degrees on the rim (convert.rail_wheel)
        "band_hz": (100.0, 4900.0),  # above the suspension, below the analyzer's 5 kHz edge
        "density": 1.0,
    },
    "liege-aircraft": {
        "title": "free aluminium aircraft model, roving hammer (University of Liège course data)",
        "source": "github.com/Renkinios/MECA0062-1_vibration_testing at c0161cf, data/sec_lab and data/node_shock.csv "
                  "(no licence stated; ULiège MECA0062 Vibration Testing and Experimental Modal Analysis, 2024): "
                  "DataPhysics SignalCalc MAT exports",
        "folder": "MECA0062-1_vibration_testing/data",
        "test": "fuselage box, 1.5 m wing, tails, two engine masses, hung free; 74 hammer points (56 on the wing and "
                "12 on the horizontal tail along z, 6 on the fin along x), 3 fixed accelerometers (H1_2 and H1_3, "
                "the wing tip's and the horizontal tail tip's, along z; H1_4, the fin's, along x); the 68 points "
                "along z read (a shape is one component of the motion: modalctl refuses points along several axes), "
                "with the three accelerometers as three inputs; accelerance (g/N, written as m/s^2/N) 0-200 Hz "
                "every 0.125 Hz, with coherence; the points laid on the wing's plane (modalctl refuses the measured "
                "3-D layout)",
        # src/main.py, modal_analysis_with_comparaison: lambda_pole, f = |lambda| / 2 pi, zeta = -Re / |lambda|
        "published_hz": [18.8426, 40.1224, 87.8520, 89.6525, 97.0713, 105.1997, 118.0131, 125.2137, 125.5837,
                         129.9523, 135.2762, 143.3719, 166.2661],
        "published_zeta": [0.00354, 0.00398, 0.00551, 0.00366, 0.00108, 0.00048, 0.00424, 0.00396, 0.00418,
                           0.00673, 0.00880, 0.00657, 0.00135],
        "published_by": "the author's own PolyMAX poles, hard-coded in src/main.py (modal_analysis_with_comparaison, "
                        "lambda_pole; f = |lambda| / 2 pi, zeta = -Re lambda / |lambda|), picked from his "
                        "stabilisation diagram of all 74 x 3 FRFs at 13-180 Hz",
        "remarks": "Damping: the accelerometers' signals carry an exponential window (W2 / X2 falls to 0.333 at 7.9 "
                   "s, a time constant of 7.2 s), which adds 1 / (2 pi f tau) to every damping: 0.117% at 18.8 Hz, "
                   "0.055% at 40.1 Hz, 0.021% at 105.2 Hz; neither the published values nor modalctl's nor the "
                   "peer's correct it (the structure's own damping at 18.8 Hz is about 0.22%, not 0.35%). By the "
                   "published damping the half-power bands of 18.8, 97.1 and 105.2 Hz span 1.1, 1.7 and 0.8 lines of "
                   "0.125 Hz: modalctl fits those poles on all 204 FRFs jointly ('+-'). 125.21 and 125.58 Hz: the "
                   "FRFs of H1_3 and H1_4 peak at 125.25-125.375 Hz, H1_2's at 125.625 Hz, and the second singular "
                   "value of the three accelerometers' FRFs rises there (2.35 against 1.3 around): two modes 0.37 Hz "
                   "apart, a third of their half-power width (1.0 Hz); the author separated them, and so does "
                   "modalctl: the one pole its LSCF finds between them (125.43 Hz) leaves residues whose second "
                   "singular value over the three accelerometers is 0.22 of the first (at most 0.07 at the other "
                   "modes the lines resolve), so it is fitted as two (modalctl.identify.multiref). 135.28 Hz: "
                   "stable in the three accelerometers' stacked diagram in some runs and doubtful in others as "
                   "round-off falls (the fin's accelerometer, seeing it weakly, moves it; with the two along z "
                   "alone it is found at 135.27 Hz); where doubtful, the wing tip's accelerometer's own diagram "
                   "holds it and it is kept (modalctl.identify.multiref). Its residues have a second shape (0.29 "
                   "of the first) that two poles do not fit, and one pole fitted on all puts it at 135.52 Hz: it "
                   "is read on the wing tip's accelerometer, whose FRFs one pole explains best (misfit 0.03; the "
                   "fin's 0.98), at 135.30 Hz. 39.625 "
                   "Hz: a peak beside the 40.1 Hz mode, in the data and named by the other team's peak picking of "
                   "the same structure (github.com/QUICKguils/vibtest, src/vibtest/project/preliminary_ema.py, "
                   "SPOTTED_PEAKS_RANGE (39, 39.6), 'freq 2') but not in this table; modalctl leaves it out "
                   "(doubtful). Layout: the fin's six points, hit along x, are left out (a shape is one component); "
                   "the others are laid on the wing's plane, the shapes read on them. The peer (LSCF order 60 on the "
                   "204 FRFs) has no pole within 1% of 18.8, 87.9, 105.2, 118.0, 130.0 and 166.3 Hz (its closest "
                   "picks are other modes'), so the MAC to it is given where it has one; its one pole at 125.58 Hz "
                   "stands for both of the pair, its shape their blend, so the MAC of the two to it is no test of "
                   "either. Last column: each mode's shapes as each accelerometer reads them (the pair's 0.84 and "
                   "0.83, its one pole's 0.67 before the split).",
        "also_seen_hz": [39.625],  # QUICKguils/vibtest, preliminary_ema.py SPOTTED_PEAKS_RANGE: (39, 39.6), 'freq 2'
        "band_hz": (10.0, 180.0),  # suspension at 0.75 and 1.4 Hz, the analyzer's edge at 200 Hz
        "density": 1.0,
    },
}


ALSO_SEEN = 0.05  # a mode the publication names near a frequency ('near 2100 Hz') is within this of it


def published_points(spec: dict) -> np.ndarray | None:
    """Where the published shapes' points are, in the coordinates the reader gives the file's
    points (the tool's along its axis, the wheel's on the rim's plane), or None."""
    if spec.get("shape_points") == "tool":
        return np.array(convert.TOOL_POINTS_M)[:, None]
    if spec.get("shape_points") == "wheel":
        angles = np.radians(15.0 * np.arange(12))
        return convert.WHEEL_RADIUS_M * np.column_stack([np.cos(angles), np.sin(angles)])
    return None


def load(name: str, data: Path) -> Path | None:
    """``<data>/<name>.uff``, converted from the fetched folder when only that is there; None if neither."""
    uff = data / f"{name}.uff"
    if uff.is_file():
        return uff
    folder = data / SETS[name]["folder"]
    if not folder.is_dir():
        return None
    return convert.SETS[name](folder, uff)


def peer(frfs: list, published: list[float]) -> dict:
    """sdypy-EMA's LSCF on the same FRFs (as accelerance, every input's rows stacked), poles closest
    to the published frequencies; its shapes (k, rows), the rows of input ``a`` at ``a * points``."""
    from sdypy import EMA

    frf = frfs[0]
    values = np.vstack([f.values for f in frfs]) * 2j * np.pi * frf.frequencies  # mobility back to accelerance
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = EMA.Model(values, frf.frequencies, lower=frf.frequencies[0], upper=frf.frequencies[-1],
                          pol_order_high=PEER_ORDER, frf_type="accelerance")
        model.get_poles(show_progress=False)
        model.select_closest_poles(published)
        model.get_constants(whose_poles="own", FRF_ind="all")
        shapes = np.real(model.normal_mode()).T  # (k, n)
    return {"f_hz": np.asarray(model.nat_freq, float), "zeta": np.asarray(model.nat_xi, float), "shapes": shapes,
            "seconds": time.perf_counter() - start}


def shape_mac(shape: np.ndarray, peer_shapes: np.ndarray, j: int, n: int) -> float:
    """MAC of one identified shape (n,) to the peer's mode ``j``: the best over the inputs stacked
    in the peer's rows (modalctl takes each shape from the input that drives the mode best)."""
    return float(max(mac(shape[None], b[None])[0] for b in peer_shapes[j].reshape(-1, n)))


def file_says(frfs: list, survey, i: int) -> dict:
    """What the file itself says of returned mode ``i``: where its peak spans fewer lines than
    resolve a pole, its frequency's jackknife standard error over the FRFs (Hz); with several
    inputs, the MAC between the shapes each input gives (the same mode: they should agree)."""
    model = survey.model
    f, zeta = float(model.frequencies[i]), float(model.damping[i])
    df = frfs[0].frequencies[1] - frfs[0].frequencies[0]
    out = {}
    if under_resolved(f, zeta, df):  # the joint fit identify made the mode of, else fitted here
        good = survey.poles.only_resolved()
        pole = good.poles[int(np.argsort(good.frequencies)[i])]
        frf = FRF.stack(frfs) if len(frfs) > 1 else frfs[0]
        out["sigma_hz"] = (pole or joint_pole(frf, f, zeta)).sigma_hz
    if len(frfs) > 1:
        shapes = [constants_of(x, model.frequencies, model.damping, i, frequency_check=False).constants for x in frfs]
        out["mac_between_inputs"] = float(mac(shapes[0][None], shapes[1][None])[0])
    return out


def mode_row(spec: dict, k: int, survey, ref: dict, forced, frfs: list) -> dict:
    """One published mode: modalctl's nearest mode within ``FOUND`` (or why the pole there was left
    out), the peer's nearest, the MACs (to the peer, with Gram-Schmidt forced, to the published
    shape) and what the file says of it (:func:`file_says`)."""
    points = frfs[0].points
    f, model, n = spec["published_hz"][k], survey.model, points.shape[0]
    i = int(np.argmin(np.abs(model.frequencies - f))) if model.n_modes else -1
    hit = i >= 0 and abs(model.frequencies[i] / f - 1) <= FOUND
    # a returned mode counts for the published mode nearest it only (one pole for two close ones is one)
    published = np.array(spec["published_hz"], float)
    nearer = float(published[int(np.argmin(np.abs(published - model.frequencies[i])))]) if hit else f
    hit = hit and nearer == f
    j = int(np.argmin(np.abs(ref["f_hz"] - f)))
    peer_hit = abs(ref["f_hz"][j] / f - 1) <= FOUND  # the peer's pole nearest the published one is near it
    why = [p["reason"] for p in survey.poles.summary() if not p["resolved"] and abs(p["f_hz"] / f - 1) <= FOUND]
    row = {"published_hz": float(f), "published_zeta": None if spec["published_zeta"] is None
           else spec["published_zeta"][k], "found": bool(hit), "f_hz": float(model.frequencies[i]) if hit else None,
           "zeta": float(model.damping[i]) if hit else None, "peer_f_hz": float(ref["f_hz"][j]),
           "peer_zeta": float(ref["zeta"][j]),
           "mac_to_peer": shape_mac(model.shapes[i], ref["shapes"], j, n) if hit and peer_hit else None,
           "mac_to_peer_with_gram_schmidt": shape_mac(forced.shapes[i], ref["shapes"], j, n)
           if hit and peer_hit and forced is not None else None,
           "left_out_because": why[0] if why and not hit else "",
           "nearest_returned_hz": float(model.frequencies[i]) if i >= 0 else None,
           **({"nearer_published_hz": nearer} if nearer != f else {}),
           **(file_says(frfs, survey, i) if hit else {})}
    where, shape = published_points(spec), spec.get("published_shapes", {}).get(f)
    if shape is not None and where is not None:
        shape = np.array(shape)[[int(np.argmin(np.linalg.norm(where - p, axis=1))) for p in points]]
        row["mac_to_published"] = float(mac(model.shapes[i][None], shape[None])[0]) if hit else None
        row["peer_mac_to_published"] = float(max(mac(b[None], shape[None])[0]
                                                 for b in ref["shapes"][j].reshape(-1, n))) if peer_hit else None
    return row


def score(name: str, path: Path) -> dict:
    """modalctl (``auto``, and ``sdof`` for its time) and the peer on one set, against the published values."""
    spec = SETS[name]
    published = np.array(spec["published_hz"])
    frfs = [f.band(*spec["band_hz"]) for f in read_uff58_references(path)]
    given = frfs if len(frfs) > 1 else frfs[0]
    start = time.perf_counter()
    survey = identify_frf(given, spec["density"], "auto")
    seconds = time.perf_counter() - start
    start = time.perf_counter()
    try:
        sdof = identify_frf(given, spec["density"], "sdof").model.frequencies
    except ModelError:  # no mode resolved
        sdof = np.zeros(0)
    sdof_seconds = time.perf_counter() - start
    shaken = round_off(given, spec["density"], survey.model.frequencies)
    ref = peer(frfs, list(published))
    model, frf = survey.model, frfs[0]
    # what Gram-Schmidt always on did (none: more modes than points, which it cannot make orthonormal)
    forced = orthonormalize_model(model) if 1 < model.n_modes <= model.grid.n else None if model.n_modes > 1 else model
    rows = [mode_row(spec, k, survey, ref, forced, frfs) for k in range(published.size)]
    also = np.array(spec.get("also_seen_hz", [np.inf]))
    far = [float(f) for f in model.frequencies if np.min(np.abs(f / published - 1)) > FOUND]
    named = [f for f in far if np.min(np.abs(f / also - 1)) <= ALSO_SEEN]
    sdof_found = sum(bool(np.any(np.abs(sdof / f - 1) <= FOUND)) for f in published)
    magnitude = np.mean([f.mean_magnitude() for f in frfs], axis=0)
    step = max(1, frf.frequencies.size // 4000)
    return {**{k: v for k, v in spec.items() if k not in ("folder", "published_shapes")}, "file": path.name,
            "inputs": len(frfs), "points": int(frf.values.shape[0]), "lines": int(frf.frequencies.size),
            "modes": rows, "spurious_hz": [f for f in far if f not in named], "named_not_tabulated_hz": named,
            "seconds": seconds, "sdof_found": int(sdof_found), "sdof_seconds": sdof_seconds,
            "peer_seconds": ref["seconds"], "notes": survey.notes, "orthogonalized": survey.orthogonalized,
            "mean_mobility": {"f_hz": frf.frequencies[::step].tolist(), "h": magnitude[::step].tolist()},
            "identified_hz": model.frequencies.tolist(), "peer_hz": ref["f_hz"].tolist(), "unit": frf.unit,
            "round_off": shaken}


def round_off(given, density: float, returned: np.ndarray) -> dict:
    """``auto`` again on the file with every value changed by ``ROUND_OFF`` (relative, a seeded normal
    draw, ``ROUND_OFF_DRAWS`` times): the modes each run returns, and those not returned by every run
    (within ``FOUND`` of one another) with ``returned``, the unchanged file's."""
    frfs = given if isinstance(given, list) else [given]
    rng = np.random.default_rng(0)
    runs = [np.asarray(returned, float)]
    for _ in range(ROUND_OFF_DRAWS):
        changed = [replace(f, values=f.values * (1 + ROUND_OFF * rng.standard_normal(f.values.shape))) for f in frfs]
        try:
            runs.append(identify_frf(changed if len(changed) > 1 else changed[0], density, "auto").model.frequencies)
        except ModelError:
            runs.append(np.zeros(0))
    every = []  # each mode any run returned, once (the first of those within FOUND of one another)
    for f in sorted(float(f) for run in runs for f in run):
        if not every or f / every[-1] - 1 > FOUND:
            every.append(f)
    in_all = lambda f: all(run.size and np.min(np.abs(run / f - 1)) <= FOUND for run in runs)  # noqa: E731
    return {"relative_change": ROUND_OFF, "runs_hz": [run.tolist() for run in runs[1:]],
            "come_and_go_hz": [f for f in every if not in_all(f)]}


def mode_line(m: dict, with_shapes: bool = False, with_inputs: bool = False) -> str:
    """One published mode's row of the table (``with_shapes``: the columns of the MAC to the published shape;
    ``with_inputs``: that of the MAC between the inputs' shapes)."""
    sigma = f" +- {m['sigma_hz']:.3f}" if m.get("sigma_hz") is not None else ""
    ours = (f"{m['f_hz']:.3f}{sigma}", f"{100 * (m['f_hz'] / m['published_hz'] - 1):+.3f}%") if m["found"] \
        else ("left out", "")
    number = lambda v, form: "" if v is None else format(v, form)  # noqa: E731
    published = "" if not with_shapes else \
        f" | {number(m.get('mac_to_published'), '.4f')} | {number(m.get('peer_mac_to_published'), '.4f')}"
    return (f"| {m['published_hz']:g} | {ours[0]} | {ours[1]} | {m['peer_f_hz']:.3f} | "
            f"{100 * (m['peer_f_hz'] / m['published_hz'] - 1):+.3f}% | {number(m['published_zeta'], '.4f')} | "
            f"{number(m['zeta'], '.5f')} | {m['peer_zeta']:.5f} | {number(m['mac_to_peer'], '.4f')} | "
            f"{number(m.get('mac_to_peer_with_gram_schmidt'), '.4f')}{published}"
            + (f" | {number(m.get('mac_between_inputs'), '.3f')}" if with_inputs else "") + " |")


def set_section(name: str, s: dict) -> list[str]:
    """The markdown section of one set: what it is, the counts, the table, why modes were left out, the notes."""
    found = sum(m["found"] for m in s["modes"])
    inputs = "" if s.get("inputs", 1) == 1 else f" from each of {s['inputs']} inputs"
    named = s.get("named_not_tabulated_hz", [])
    with_shapes = any("mac_to_published" in m for m in s["modes"])
    with_inputs = any("mac_between_inputs" in m for m in s["modes"])
    head = ("| published (Hz) | modalctl (Hz) | error | sdypy-EMA (Hz) | error | zeta published | zeta modalctl "
            "| zeta sdypy-EMA | MAC to peer | MAC had Gram-Schmidt been forced |"
            + (" MAC to published shape | peer's MAC to it |" if with_shapes else "")
            + (" MAC between the inputs' shapes |" if with_inputs else ""))
    lines = [f"## {name}: {s['title']}", "", f"Source: {s['source']}. Test: {s['test']}. Published by "
             f"{s['published_by']}. Band {s['band_hz'][0]:g}-{s['band_hz'][1]:g} Hz, {s['points']} points{inputs}, "
             f"{s['lines']} lines.", "",
             f"modalctl (auto) found **{found} of {len(s['modes'])}** published modes in {s['seconds']:.2f} s "
             f"(sdof: {s['sdof_found']} in {s['sdof_seconds']:.2f} s; sdypy-EMA {s['peer_seconds']:.2f} s); "
             f"spurious modes inside the band (farther than {FOUND:.0%} from every published one): "
             f"{', '.join(f'{f:.1f} Hz' for f in s['spurious_hz']) or 'none'}"
             + (f"; near a mode the publication names but does not tabulate: "
                f"{', '.join(f'{f:.1f} Hz' for f in named)}" if named else "")
             + f"; Gram-Schmidt {'applied' if s['orthogonalized'] else 'not applied'}.", "", head,
             "|" + "---|" * (head.count("|") - 1)]
    lines += [mode_line(m, with_shapes, with_inputs) for m in s["modes"]]
    lines += ["", f"What the file shows: {s['remarks']}", ""] if s.get("remarks") else [""]
    if s.get("round_off"):
        shaken = s["round_off"]
        runs = "; ".join(", ".join(f"{f:.1f}" for f in run) for run in shaken["runs_hz"])
        lines += [f"Round-off: `auto` on the file with every value changed by {shaken['relative_change']:g} (relative, "
                  f"{len(shaken['runs_hz'])} seeded draws) returned {runs} Hz; "
                  + (f"modes that come and go between the three runs: "
                     f"{', '.join(f'{f:.1f}' for f in shaken['come_and_go_hz'])} Hz "
                     f"(LSCF's normal equations are numerically singular in the orders its poles are picked from: "
                     f"`modalctl.identify.lscf`)" if shaken["come_and_go_hz"] else "the same modes") + ".", ""]
    for m in s["modes"]:
        near = m.get("nearest_returned_hz")
        if not m["found"] and m["left_out_because"]:
            lines.append(f"- {m['published_hz']:g} Hz left out: {m['left_out_because']}")
        elif not m["found"] and m.get("nearer_published_hz") is not None:
            lines.append(f"- {m['published_hz']:g} Hz: the mode returned within {FOUND:.0%}, {near:.3f} Hz "
                         f"({100 * (near / m['published_hz'] - 1):+.2f}%), is nearer the published "
                         f"{m['nearer_published_hz']:g} Hz and counts for it: one pole for the two")
        elif not m["found"] and near is not None:
            lines.append(f"- {m['published_hz']:g} Hz: no pole within {FOUND:.0%}; the nearest mode returned is "
                         f"{near:.1f} Hz ({100 * (near / m['published_hz'] - 1):+.2f}%)")
    return lines + ["", "Notes of the identification:", ""] + [f"- {n}" for n in s["notes"]] + [""]


def report(data: dict, path: Path) -> None:
    sets = data["sets"]
    lines = ["# Identification on real measurements, default options, blind", "",
             "`python benchmarks/identify_real.py --data DIR` (the sources fetched; see the script's docstring). "
             "modalctl: `identify_frf(..., 'auto')` on the file as exported (its 0 Hz bin, its directions, its "
             "units), within the band given; no frequency given. sdypy-EMA: LSCF order "
             f"{PEER_ORDER}, poles closest to the published frequencies. Found: within {FOUND:.0%}; MAC to the "
             "peer's normal modes on the same points (of the input whose rows fit best, when there are several). "
             "'f +- s': a mode whose half-power band spans fewer than 3 lines, fitted on all FRFs jointly, and the "
             "jackknife standard error of its frequency over the FRFs (Hz). Round-off: `auto` again on each file "
             f"with every value changed by {ROUND_OFF:g} (relative, {ROUND_OFF_DRAWS} seeded draws, far below any "
             "measurement's noise); a mode not returned by every run is listed under its set and drawn orange.",
             ""]
    load = data.get("machine", {}).get("load_average_1_5_15_min")
    if load:
        lines += [f"Times on {data['machine']['cpus']} cores ({data['machine'].get('cpu', 'processor not recorded')}) "
                  f"at a load average of {load[0]:.1f} (the benchmark counts about one; more is other work sharing "
                  "them).", ""]
    missing = data.get("missing", [])
    if missing:
        lines += [f"Not run (not fetched): {', '.join(missing)}.", ""]
    for name, s in sets.items():
        lines += set_section(name, s)
    RESULTS.joinpath(f"{NAME}.md").write_text("\n".join(lines) + "\n")
    fig, axes = plt.subplots(len(sets), 1, figsize=(10, 3.2 * max(1, len(sets))), squeeze=False)
    for ax, (name, s) in zip(axes[:, 0], sets.items()):
        ax.semilogy(s["mean_mobility"]["f_hz"], s["mean_mobility"]["h"], lw=0.6, color="0.4")
        for k, f in enumerate(s["modes"]):
            ax.axvline(f["published_hz"], color="tab:green", lw=3, alpha=0.35, label="published" if k == 0 else None)
        shaken = np.array(s.get("round_off", {}).get("come_and_go_hz") or [np.inf])
        moved = [f for f in s["identified_hz"] if np.min(np.abs(shaken / f - 1)) <= FOUND]
        for k, f in enumerate(f for f in s["identified_hz"] if f not in moved):
            ax.axvline(f, color="k", lw=0.8, ls="--", label="modalctl (auto)" if k == 0 else None)
        for k, f in enumerate(moved):
            ax.axvline(f, color="tab:orange", lw=1.0, ls=":",
                       label=f"modalctl, not in every run of the file changed by {ROUND_OFF:g}" if k == 0 else None)
        ax.plot(s["peer_hz"], np.full(len(s["peer_hz"]), max(s["mean_mobility"]["h"])), "rv", ms=6,
                label="sdypy-EMA (given published f)")
        found = sum(m["found"] for m in s["modes"])
        ax.set(xlabel="frequency (Hz)", ylabel=f"mean |H| ({s['unit']})", xlim=s["band_hz"],
               title=f"{name}: modalctl found {found} of {len(s['modes'])} published modes, "
                     f"{len(s['spurious_hz'])} spurious in the band")
        ax.legend(fontsize=7, loc="lower right")
    save_figure(fig, NAME)
    print(f"wrote {path}, {RESULTS / (NAME + '.md')}, {RESULTS / (NAME + '.png')}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path(os.environ.get("MODALCTL_REAL_DATA", "real_data_fetched")),
                        help="folder of the fetched sources or converted files (env MODALCTL_REAL_DATA)")
    parser.add_argument("--report-only", action="store_true")
    args = parser.parse_args()
    sets, missing = {}, []
    for name in SETS:
        path = load(name, args.data)
        if path is None:
            missing.append(name)
            print(f"{name}: not in {args.data} (fetch {SETS[name]['source'].split(',')[0]})", file=sys.stderr)
            continue
        sets[name] = score(name, path)
    if not sets:  # the results committed are left as they are: a run without the data measured nothing
        print(f"identify_real.py: error: none of the {len(SETS)} measured sets is in {args.data}: give --data DIR "
              f"(or MODALCTL_REAL_DATA); results/{NAME}.* left as they are", file=sys.stderr)
        sys.exit(2)
    path = write_json(NAME, {"sets": sets, "missing": missing, "machine": machine()})
    report(*read_json(NAME))
    print(path)


if __name__ == "__main__":
    if "--report-only" in sys.argv:
        report(*read_json(NAME))
    else:
        main()
