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
A published mode is *found* when a returned mode lies within 1% of it; a returned mode farther
than 1% from every published one is *spurious*. Shapes are compared by MAC to the peer's
(sdypy-EMA's normal modes) on the same points.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from common import RESULTS, read_json, save_figure, write_json  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent / "real_data"))
import convert  # noqa: E402

from modalctl.identify.survey import identify_frf, mac  # noqa: E402
from modalctl.identify.uff import read_uff58  # noqa: E402
from modalctl.model.modes import ModelError  # noqa: E402
from modalctl.model.projection import orthonormalize_model  # noqa: E402

NAME = "identify_real"
FOUND = 0.01  # a published mode is found within this relative distance
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
        "published_by": "its README: peaks of Im H and half-power points of Re H, read by hand",
        "band_hz": (100.0, 3500.0),  # Proj_3.m fits 101-3500 Hz
        "density": 1.0,
    },
}


def load(name: str, data: Path) -> Path | None:
    """``<data>/<name>.uff``, converted from the fetched folder when only that is there; None if neither."""
    uff = data / f"{name}.uff"
    if uff.is_file():
        return uff
    folder = data / SETS[name]["folder"]
    if not folder.is_dir():
        return None
    return convert.SETS[name](folder, uff)


def peer(frf, published: list[float]) -> dict:
    """sdypy-EMA's LSCF on the same FRFs (as accelerance), poles closest to the published frequencies."""
    from sdypy import EMA

    values = frf.values * 2j * np.pi * frf.frequencies  # mobility back to accelerance
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


def score(name: str, path: Path) -> dict:
    """modalctl (``auto``, and ``sdof`` for its time) and the peer on one set, against the published values."""
    spec = SETS[name]
    published = np.array(spec["published_hz"])
    frf = read_uff58(path).band(*spec["band_hz"])
    start = time.perf_counter()
    survey = identify_frf(frf, spec["density"], "auto")
    seconds = time.perf_counter() - start
    start = time.perf_counter()
    try:
        sdof = identify_frf(frf, spec["density"], "sdof").model.frequencies
    except ModelError:  # no mode resolved
        sdof = np.zeros(0)
    sdof_seconds = time.perf_counter() - start
    ref = peer(frf, list(published))
    model = survey.model
    rows = []
    for k, f in enumerate(published):
        i = int(np.argmin(np.abs(model.frequencies - f))) if model.n_modes else -1
        hit = i >= 0 and abs(model.frequencies[i] / f - 1) <= FOUND
        j = int(np.argmin(np.abs(ref["f_hz"] - f)))
        why = [p["reason"] for p in survey.poles.summary() if not p["resolved"] and abs(p["f_hz"] / f - 1) <= FOUND]
        rows.append({"published_hz": float(f), "published_zeta": None if spec["published_zeta"] is None
                     else spec["published_zeta"][k], "found": bool(hit),
                     "f_hz": float(model.frequencies[i]) if hit else None,
                     "zeta": float(model.damping[i]) if hit else None,
                     "peer_f_hz": float(ref["f_hz"][j]), "peer_zeta": float(ref["zeta"][j]),
                     "mac_to_peer": float(mac(model.shapes[i:i + 1], ref["shapes"][j:j + 1])[0]) if hit else None,
                     "left_out_because": why[0] if why and not hit else ""})
    forced = orthonormalize_model(model) if model.n_modes > 1 else model  # what Gram-Schmidt always on did
    for m in rows:
        i = int(np.argmin(np.abs(model.frequencies - m["published_hz"])))
        j = int(np.argmin(np.abs(ref["f_hz"] - m["published_hz"])))
        m["mac_to_peer_with_gram_schmidt"] = float(mac(forced.shapes[i:i + 1], ref["shapes"][j:j + 1])[0]) \
            if m["found"] else None
    spurious = [float(f) for f in model.frequencies if np.min(np.abs(f / published - 1)) > FOUND]
    sdof_found = sum(bool(np.any(np.abs(sdof / f - 1) <= FOUND)) for f in published)
    return {**{k: v for k, v in spec.items() if k != "folder"}, "file": path.name, "points": int(frf.values.shape[0]),
            "lines": int(frf.frequencies.size), "modes": rows, "spurious_hz": spurious, "seconds": seconds,
            "sdof_found": int(sdof_found), "sdof_seconds": sdof_seconds, "peer_seconds": ref["seconds"],
            "notes": survey.notes, "orthogonalized": survey.orthogonalized,
            "mean_mobility": {"f_hz": frf.frequencies[::8].tolist(), "h": frf.mean_magnitude()[::8].tolist()},
            "identified_hz": model.frequencies.tolist(), "peer_hz": ref["f_hz"].tolist(), "unit": frf.unit}


def report(data: dict, path: Path) -> None:
    sets = data["sets"]
    lines = ["# Identification on real measurements, default options, blind", "",
             "`python benchmarks/identify_real.py --data DIR` (the sources fetched; see the script's docstring). "
             "modalctl: `identify_frf(..., 'auto')` on the file as exported (its 0 Hz bin, its directions, its "
             "units), within the band given; no frequency given. sdypy-EMA: LSCF order "
             f"{PEER_ORDER}, poles closest to the published frequencies. Found: within {FOUND:.0%}; MAC to the "
             "peer's normal modes on the same points.", ""]
    missing = data.get("missing", [])
    if missing:
        lines += [f"Not run (not fetched): {', '.join(missing)}.", ""]
    for name, s in sets.items():
        found = sum(m["found"] for m in s["modes"])
        lines += [f"## {name}: {s['title']}", "", f"Source: {s['source']}. Test: {s['test']}. Published by "
                  f"{s['published_by']}. Band {s['band_hz'][0]:g}-{s['band_hz'][1]:g} Hz, {s['points']} points, "
                  f"{s['lines']} lines.", "",
                  f"modalctl (auto) found **{found} of {len(s['modes'])}** published modes in {s['seconds']:.2f} s "
                  f"(sdof: {s['sdof_found']} in {s['sdof_seconds']:.2f} s; sdypy-EMA {s['peer_seconds']:.2f} s); "
                  f"spurious modes inside the band: {', '.join(f'{f:.1f} Hz' for f in s['spurious_hz']) or 'none'}; "
                  f"Gram-Schmidt {'applied' if s['orthogonalized'] else 'not applied'}.", "",
                  "| published (Hz) | modalctl (Hz) | error | sdypy-EMA (Hz) | error | zeta published | zeta modalctl "
                  "| zeta sdypy-EMA | MAC to peer | MAC had Gram-Schmidt been forced |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for m in s["modes"]:
            ours = (f"{m['f_hz']:.3f}", f"{100 * (m['f_hz'] / m['published_hz'] - 1):+.3f}%") if m["found"] \
                else ("left out", "")
            zp = "" if m["published_zeta"] is None else f"{m['published_zeta']:.4f}"
            zo = "" if m["zeta"] is None else f"{m['zeta']:.5f}"
            mc = "" if m["mac_to_peer"] is None else f"{m['mac_to_peer']:.4f}"
            gs = "" if m.get("mac_to_peer_with_gram_schmidt") is None else f"{m['mac_to_peer_with_gram_schmidt']:.4f}"
            lines.append(f"| {m['published_hz']:g} | {ours[0]} | {ours[1]} | {m['peer_f_hz']:.3f} | "
                         f"{100 * (m['peer_f_hz'] / m['published_hz'] - 1):+.3f}% | {zp} | {zo} | "
                         f"{m['peer_zeta']:.5f} | {mc} | {gs} |")
        lines += [""] + [f"- {m['published_hz']:g} Hz left out: {m['left_out_because']}" for m in s["modes"]
                         if not m["found"] and m["left_out_because"]]
        lines += ["", "Notes of the identification:", ""] + [f"- {n}" for n in s["notes"]] + [""]
    RESULTS.joinpath(f"{NAME}.md").write_text("\n".join(lines) + "\n")
    fig, axes = plt.subplots(len(sets), 1, figsize=(10, 3.4 * max(1, len(sets))), squeeze=False)
    for ax, (name, s) in zip(axes[:, 0], sets.items()):
        ax.semilogy(s["mean_mobility"]["f_hz"], s["mean_mobility"]["h"], lw=0.6, color="0.4")
        for k, f in enumerate(s["modes"]):
            ax.axvline(f["published_hz"], color="tab:green", lw=3, alpha=0.35, label="published" if k == 0 else None)
        for k, f in enumerate(s["identified_hz"]):
            ax.axvline(f, color="k", lw=0.8, ls="--", label="modalctl (auto)" if k == 0 else None)
        ax.plot(s["peer_hz"], np.full(len(s["peer_hz"]), max(s["mean_mobility"]["h"])), "rv", ms=6,
                label="sdypy-EMA (given published f)")
        found = sum(m["found"] for m in s["modes"])
        ax.set(xlabel="frequency (Hz)", ylabel=f"mean |H| over points ({s['unit']})",
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
    path = write_json(NAME, {"sets": sets, "missing": missing})
    report(*read_json(NAME))
    print(path)


if __name__ == "__main__":
    if "--report-only" in sys.argv:
        report(*read_json(NAME))
    else:
        main()
