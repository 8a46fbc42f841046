"""Where identification fails: error against mode spacing over bandwidth, and against noise.

    python benchmarks/identify_limits.py   # writes benchmarks/results/identify_limits.{json,png}

Two modes (1 kHz, zeta 1%, and a second one spaced by r half-power bandwidths, 2 zeta f), with
different shapes on 41 points, FRF at 0.5 Hz resolution with complex noise 20-60 dB below the
FRF's peak (four averages, the noise level known as from the scatter between shots). For each
spacing and noise, five noise draws: the median error of the first mode, how often it is
reported unresolved instead, and how often *both* modes are returned (each within a quarter of
their spacing of the truth). The single-mode estimators (``peaks``, ``sdof``) report close modes
unresolved; the MDOF ones (``mdof``, ``auto``) return both, blind.
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from common import command_line, save_figure, write_json  # noqa: E402

from modalctl.identify.estimators import peak_picking, sdof_fit  # noqa: E402
from modalctl.identify.frf import FRF, mobility  # noqa: E402
from modalctl.identify.mdof import auto_fit, mdof_fit  # noqa: E402

ZETA, F1 = 0.01, 1000.0
X = np.linspace(0, 0.1, 41)
SHAPES = np.array([50 * np.sin(np.pi * X / 0.1), 50 * np.sin(3 * np.pi * X / 0.1)])
SPACINGS = np.geomspace(0.25, 8, 14)
SNRS = (20, 30, 40, 60)
DRAWS = 5


def frf(spacing: float, snr: float, seed: int, averages: int = 4) -> FRF:
    freqs = np.arange(500, 2000, 0.5)
    f2 = F1 * (1 + 2 * ZETA * spacing)
    h = mobility(freqs, [F1, f2], [ZETA, ZETA], SHAPES)
    sigma = np.abs(h).max() / 10 ** (snr / 20) / np.sqrt(averages)
    rng = np.random.default_rng(seed)
    h = h + sigma * (rng.standard_normal(h.shape) + 1j * rng.standard_normal(h.shape)) / np.sqrt(2)
    return FRF(freqs, h, np.ones(h.shape), X[:, None], 0, averages, 0.0, np.full(h.shape, sigma))


def first_mode(modes, spacing: float) -> tuple[float, float, bool, bool]:
    """Errors of the mode nearest to F1 (NaN when none), whether it was called resolved, and
    whether both modes were returned resolved, each within a quarter of the spacing."""
    if modes.n_modes == 0:
        return np.nan, np.nan, False, False
    i = int(np.argmin(np.abs(modes.frequencies - F1)))
    f2 = F1 * (1 + 2 * ZETA * spacing)
    good = modes.frequencies[modes.resolved]
    both = all(good.size and np.min(np.abs(good - f)) < (f2 - F1) / 4 for f in (F1, f2))
    return modes.frequencies[i] / F1 - 1, modes.damping[i] / ZETA - 1, bool(modes.resolved[i]), bool(both)


def main() -> None:
    methods = {"peaks": peak_picking, "sdof": sdof_fit, "mdof": mdof_fit, "auto": auto_fit}
    results = {name: {str(snr): [] for snr in SNRS} for name in methods}
    for name, method in methods.items():
        for snr in SNRS:
            for spacing in SPACINGS:
                draws = [first_mode(method(frf(spacing, snr, seed)), spacing) for seed in range(DRAWS)]
                resolved = [d for d in draws if d[2]]
                results[name][str(snr)].append({
                    "spacing": float(spacing),
                    "resolved_fraction": len(resolved) / DRAWS,
                    "both_fraction": sum(d[3] for d in draws) / DRAWS,
                    "median_abs_f_err": float(np.median([abs(d[0]) for d in resolved])) if resolved else None,
                    "median_abs_zeta_err": float(np.median([abs(d[1]) for d in resolved])) if resolved else None,
                    "median_abs_zeta_err_all": float(np.nanmedian([abs(d[1]) for d in draws])),
                })
    path = write_json("identify_limits", {"zeta": ZETA, "f1_hz": F1, "draws": DRAWS, "results": results})
    plot(results)
    for name in methods:
        for snr in ("40", "20"):
            row = results[name][snr]
            both = [r["spacing"] for r in row if r["both_fraction"] == 1]
            print(f"{name}, {snr} dB: both modes returned in every draw at spacings "
                  f"{', '.join(f'{x:.2f}' for x in both) or 'none'} (bandwidths)")
    print(f"wrote {path}")


def plot(results: dict) -> None:
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.3))
    colours = dict(zip(map(str, SNRS), plt.cm.viridis(np.linspace(0, 0.85, len(SNRS)))))
    for name, ls in (("peaks", "--"), ("sdof", "-"), ("auto", ":")):
        for snr, rows in results[name].items():
            s = [r["spacing"] for r in rows]
            axes[0].loglog(s, [r["median_abs_zeta_err"] or np.nan for r in rows], ls, color=colours[snr],
                           label=f"{name} {snr} dB")
            axes[1].semilogx(s, [r["both_fraction"] for r in rows], ls, color=colours[snr], marker=".",
                             label=f"{name} {snr} dB" if snr in ("20", "40") else None)
    for ax in axes[:2]:
        ax.axvline(1, color="k", lw=0.6)
    axes[0].set(xlabel="spacing / half-power bandwidth", ylabel="median |damping error| (resolved only)",
                title="accuracy against mode spacing")
    axes[0].legend(fontsize=7, ncol=2)
    axes[1].set(xlabel="spacing / half-power bandwidth", ylabel="fraction of draws with both modes returned",
                title="close modes: single-mode fits report them, auto returns both")
    axes[1].legend(fontsize=7)
    for ax in axes[:2]:
        ax.set_xticks([0.25, 0.5, 1, 2, 4, 8], ["0.25", "0.5", "1", "2", "4", "8"])
        ax.minorticks_off()
    idx = int(np.argmin(np.abs(SPACINGS - 5)))
    for name, marker in (("peaks", "o"), ("sdof", "s"), ("auto", "*")):
        axes[2].loglog(SNRS, [results[name][str(s)][idx]["median_abs_zeta_err"] for s in SNRS], marker + "-",
                       label=f"{name}, damping")
        axes[2].loglog(SNRS, [results[name][str(s)][idx]["median_abs_f_err"] for s in SNRS], marker + ":",
                       label=f"{name}, frequency")
    axes[2].set(xlabel="SNR (dB)", ylabel="median relative error",
                title=f"against noise, spacing {SPACINGS[idx]:.1f} bandwidths")
    axes[2].legend(fontsize=7)
    save_figure(fig, "identify_limits")


if __name__ == "__main__":
    command_line()
    main()
