"""Pictures of models: an identification's (its FRFs and poles, its cross-talk, its shapes) and a
finite-element plate's (its mode shapes, its meshes' convergence)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure

from modalctl.identify.estimators import NOISE

from .figures import save as _save
from .figures import subplots as _subplots

__all__ = ["plot_identification", "plot_fe_shapes", "plot_fe_convergence"]


def _frf_panel(ax, survey):
    """Every input's mean mobility (in the file's unit: m/s/V, m/s/N) over kHz; poles kept black, left out red."""
    for a, frf in sorted(survey.frfs["sparse"].items()):
        ax.semilogy(frf.frequencies / 1e3, frf.mean_magnitude(), lw=0.7, label=f"actuator {a}")
    for f, ok, why in zip(survey.poles.frequencies, survey.poles.resolved, survey.poles.reasons):
        if ok or why != NOISE:
            ax.axvline(f / 1e3, color="k" if ok else "r", lw=0.6, ls="-" if ok else "--")
    ax.set(xlabel="frequency (kHz)", ylabel=f"mean |H| over points (m/s/{survey.model.meta.get('input_unit', 'V')})",
           title=f"mean mobility per actuator; poles found ({survey.model.n_modes} kept, red dashed: left out)")
    ax.legend(fontsize=7, ncol=4)


def _crosstalk_panel(ax, matrix: np.ndarray, title: str):
    """|cross-talk| between the modes (log colours, 1e-5 to 1), its largest off-diagonal; its image."""
    k = len(matrix)
    image = ax.imshow(np.maximum(np.abs(matrix), 1e-5), norm=LogNorm(1e-5, 1), cmap="viridis",
                      extent=(0.5, k + 0.5, k + 0.5, 0.5))
    off = np.max(np.abs(matrix - np.eye(k)))
    ax.set(title=f"{title}\nlargest off-diagonal {off:.2g}", xlabel="mode", ylabel="mode")
    return image


def _beam_shapes_panel(ax, model):
    """A beam's mode shapes over x (mm), each normalised and stacked, its resonance (kHz) beside."""
    x = model.grid.x * 1e3
    for k in range(model.n_modes):
        s = model.shapes[k] / np.max(np.abs(model.shapes[k]))
        ax.plot(x, 0.4 * s - k, lw=0.8)
        ax.text(x[-1] + 1, -k, f"{model.frequencies[k] / 1e3:.2f} kHz", fontsize=7, va="center")
    ax.set(xlabel="x (mm)", yticks=[], title="identified mode shapes (normalized, Eq 3.13)")


def plot_identification(survey, stem) -> list[str]:
    """The identification's pictures beside the model file; returns their paths: ``<stem>_frf.png``
    (mean FRF of every actuator with the poles, Fig 3.8), ``<stem>_crosstalk.png`` (before/after
    Gram-Schmidt, Fig 3.11) and ``<stem>_shapes.png`` (the identified shapes)."""
    stem = Path(stem)
    model = survey.model
    fig, ax = _subplots(figsize=(10, 4))
    _frf_panel(ax, survey)
    paths = [_save(fig, f"{stem}_frf.png")]
    fig, axes = _subplots(1, 2, figsize=(11, 4.6))
    for ax, matrix, title in zip(axes, (survey.crosstalk_before, survey.crosstalk_after),
                                 ("identified", "after Gram-Schmidt")):
        image = _crosstalk_panel(ax, matrix, title)
    fig.colorbar(image, ax=axes, label="|cross-talk| (log)")
    paths.append(_save(fig, f"{stem}_crosstalk.png"))
    if model.grid.dim == 2:
        fig = _plate_shapes(model)
    else:
        fig, ax = _subplots(figsize=(10, 5))
        _beam_shapes_panel(ax, model)
    paths.append(_save(fig, f"{stem}_shapes.png"))
    return [str(p) for p in paths]


def _plate_shape_panel(ax, model, k: int):
    """Mode ``k``'s normalised shape: on a lattice an image (massless points blank), else triangulated."""
    x, y = model.grid.points.T * 1e3
    s = model.shapes[k] / np.max(np.abs(model.shapes[k]))
    if model.grid.shape is not None:
        image = np.ma.masked_where(model.grid.mass == 0, s).reshape(model.grid.shape[::-1])
        ax.imshow(image, origin="lower", extent=(x.min(), x.max(), y.min(), y.max()), cmap="RdBu_r", vmin=-1, vmax=1)
    else:
        ax.tripcolor(x, y, s, shading="gouraud", cmap="RdBu_r", vmin=-1, vmax=1)
        ax.plot(x, y, ",k", alpha=0.4)
    ax.set_aspect("equal")
    ax.set_title(f"{k + 1}: {model.frequencies[k] / 1e3:.3f} kHz", fontsize=8)


def _plate_shapes(model, title: str = "identified mode shapes on the measured points (normalized, Eq 3.13)"):
    """A figure of one map per mode, six to a row."""
    cols = min(6, model.n_modes)
    rows = -(-model.n_modes // cols)
    fig, axes = _subplots(rows, cols, figsize=(2.2 * cols, 1.9 * rows + 0.6), squeeze=False)
    for k, ax in enumerate(axes.ravel()):
        ax.set_axis_off()
        if k < model.n_modes:
            _plate_shape_panel(ax, model, k)
    fig.suptitle(title)
    return fig


def plot_fe_shapes(model, stem) -> str:
    """``<stem>_shapes.png``: a finite-element plate's mode shapes pixel for pixel (patches outlined, sensors dotted);
    its path."""
    from matplotlib import colormaps
    (nx, ny), k, cols, (x, y) = model.grid.shape, model.n_modes, min(12, model.n_modes), model.grid.points.T
    ix = np.linspace(0, nx - 1, min(nx, 120)).round().astype(int)  # the grid sampled to 120 pixels across
    iy = np.linspace(0, ny - 1, max(2, round((ix.size - 1) * np.ptp(y) / np.ptp(x)) + 1)).round().astype(int)
    s = np.where(model.grid.mass > 0, model.shapes / np.abs(model.shapes).max(1, keepdims=True), np.nan)
    rgba, x, y = colormaps["RdBu_r"](s.reshape(k, ny, nx)[:, iy][:, :, ix] / 2 + 0.5, bytes=True), x[ix], y[iy * nx]
    at = lambda axis, metres: np.searchsorted(axis, metres).clip(1, axis.size - 1)  # noqa: E731 (pixels, y up)
    for (j0, j1), (i0, i1) in ((at(x, p["xlim_m"]), at(y, p["ylim_m"])) for p in model.meta.get("actuators", [])):
        rgba[:, i0:i1, [j0, j1 - 1]] = rgba[:, [i0, i1 - 1], j0:j1] = (0, 0, 0, 255)
    for j, i in ((at(x, q["position_m"][0]), at(y, q["position_m"][1])) for q in model.meta.get("sensors", [])):
        rgba[:, i - 1:i + 2, j - 1:j + 2] = (0, 0, 0, 255)
    rows, w, h = -(-k // cols), ix.size + max(4, ix.size // 12), iy.size + 16  # pixels of a tile, its gutter, its label
    fig = Figure(figsize=((cols * w + 0.5) / 100, (rows * h + 30.5) / 100), dpi=100)  # + 0.5: whole pixels
    for i, (x0, y0) in enumerate(zip(np.arange(k) % cols * w, (rows - 1 - np.arange(k) // cols) * h)):
        fig.figimage(rgba[i], x0, y0, origin="lower")
        fig.text(x0, y0 + iy.size + 2, f"{i + 1}: {model.frequencies[i] / 1e3:.3f} kHz", size=7, transform=None)
    fig.suptitle(f"mode shapes: {model.meta.get('model', 'finite elements')}", y=1 - 4 / (rows * h + 30), va="top")
    return str(_save(fig, f"{stem}_shapes.png", dpi=100, tight=False))  # the tiles' pixels as they are


def plot_fe_convergence(model, convergence, stem) -> str:
    """``<stem>_convergence.png``: each mesh's frequency errors against the finest, and Richardson's estimate."""
    fig, (left, right) = _subplots(1, 2, figsize=(11, 4), subplot_kw={"xlabel": "mode", "yscale": "log"})
    last, mesh = convergence.levels[-1], lambda lv: f"{lv.size * 1e3:.2g} mm, {lv.dofs} dofs, {lv.seconds:.1f} s"
    for lv, f in ((lv, lv.frequencies[:model.n_modes]) for lv in convergence.levels[:-1]):  # each mode on each mesh
        left.plot(range(1, f.size + 1), np.abs(f / last.frequencies[:f.size] - 1).clip(1e-7) * 100, "o-", ms=3,
                  label=mesh(lv))
    left.set(ylabel="|f / f(finest) - 1| (%)", title=f"each mesh against the finest ({mesh(last)})")
    right.plot(range(1, model.n_modes + 1), np.maximum(convergence.frequency_error, 1e-7) * 100, "o-", ms=3)
    right.axhline(convergence.tolerance * 100, color="r", ls="--", label=f"tolerance {convergence.tolerance:.2%}")
    right.set(ylabel="estimated error of the finest mesh (%)", title="Richardson's estimate (f_h - f_2h) / 3")
    left.legend(fontsize=7), right.legend(fontsize=7)
    return str(_save(fig, f"{stem}_convergence.png"))
