"""Pictures. The only module that imports matplotlib (with the non-interactive Agg backend)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .decompose import Decomposition  # noqa: E402

__all__ = ["plot_decomposition", "plot_modes_needed"]


def _save(fig, path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return path


def _coefficient_bars(ax, dec: Decomposition):
    labels = dec.model.labels
    c = np.abs(dec.coefficients)
    kept = np.zeros(c.size, bool)
    kept[dec.modes_used] = True
    pos = np.arange(c.size)
    if not kept.all():
        ax.bar(pos[~kept], c[~kept], color="0.75", label="dropped")
    ax.bar(pos[kept], c[kept], color="C0", label="kept")
    ax.set_xticks(pos, [str(l) for l in labels], fontsize=7)
    ax.set_xlabel("mode")
    ax.set_ylabel("|coefficient| (m/s sqrt(kg))")
    ax.legend(frameon=False)


def plot_decomposition(dec: Decomposition, path) -> Path:
    """Reference field, reduced reconstruction and target zone, over the modal coefficients."""
    m = dec.metrics()
    grid, ref, rec = dec.model.grid, dec.shape.values, dec.reconstruction
    title = (f"{dec.model.meta.get('name', 'model')}: {dec.modes_used.size} of {dec.model.n_modes} modes, "
             f"tau {m['tau']:.3f}, NRMSE {m['nrmse']:.3f}")
    if grid.dim == 1:
        fig, (top, bottom) = plt.subplots(2, 1, figsize=(8, 6.5), gridspec_kw={"height_ratios": [3, 2]})
        x = grid.x * 1e3
        top.fill_between(x, 0, 1, where=dec.shape.target_mask, transform=top.get_xaxis_transform(),
                         color="C2", alpha=0.15, label="target zone")
        top.plot(x, ref * 1e3, "C3", lw=2, label="reference")
        top.plot(x, rec * 1e3, "k--", lw=1.5, label=f"{dec.modes_used.size} modes")
        top.set_xlabel("x (mm)")
        top.set_ylabel("velocity at focus (mm/s)")
        top.legend(frameon=False, fontsize=8)
        top.set_title(title, fontsize=10)
        _coefficient_bars(bottom, dec)
    else:
        nx, ny = grid.shape
        fig = plt.figure(figsize=(11, 6.5))
        axes = [fig.add_subplot(2, 3, i + 1) for i in range(3)]
        extent = [*grid.bounds[:, 0] * 1e3, *grid.bounds[:, 1] * 1e3]
        vmax = np.abs(ref).max() * 1e3
        for ax, data, name in zip(axes, [ref, rec, rec - ref], ["reference", "reduced model", "error"]):
            im = ax.imshow(data.reshape(ny, nx) * 1e3, origin="lower", extent=extent, cmap="RdBu_r",
                           vmin=-vmax, vmax=vmax)
            ax.contour(dec.shape.target_mask.reshape(ny, nx), levels=[0.5], colors="k", linewidths=0.8,
                       extent=extent)
            ax.set_title(name, fontsize=9)
            ax.set_xlabel("x (mm)")
        axes[0].set_ylabel("y (mm)")
        fig.colorbar(im, ax=axes, label="velocity at focus (mm/s)", shrink=0.8)
        fig.suptitle(title, fontsize=10)
        _coefficient_bars(fig.add_subplot(2, 1, 2), dec)
    return _save(fig, path)


def plot_modes_needed(labels, series: dict, kept: dict, path, title: str) -> Path:
    """Max |coefficient| per mode of several pulse sets, with the kept band of each shaded.

    Parameters
    ----------
    labels : sequence of int
        Mode numbers, shape (k,).
    series : dict of str -> ndarray (k,)
        Per pulse set, the largest relative |coefficient| over its centres.
    kept : dict of str -> sequence of int
        Per pulse set, the positional indices the rule keeps.
    """
    fig, ax = plt.subplots(figsize=(9, 4.5))
    pos = np.arange(len(labels))
    width = 0.8 / len(series)
    for i, (name, values) in enumerate(series.items()):
        colour = f"C{i}"
        ax.bar(pos + (i - (len(series) - 1) / 2) * width, values, width, color=colour,
               label=f"{name}: {len(kept[name])} modes")
        if len(kept[name]):
            ax.axvspan(min(kept[name]) - 0.45, max(kept[name]) + 0.45, ymin=0.95 - 0.035 * i, ymax=0.975 - 0.035 * i,
                       color=colour, alpha=0.6)
    ax.set_ylim(0, 1.25)  # room above the bars for the kept bands
    ax.axhline(0.2, color="k", lw=0.8, ls=":", label="20% of the set's largest")
    ax.set_xticks(pos, [str(l) for l in labels], fontsize=8)
    ax.set_xlabel("mode")
    ax.set_ylabel("max over centres of |c| / max |c| of the set")
    ax.set_title(title, fontsize=10)
    ax.legend(frameon=False, fontsize=8, loc="center right")
    return _save(fig, path)
