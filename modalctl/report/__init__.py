"""Pictures of decompositions, shots, closed loops, sweeps, identifications and finite-element plates.

The only package that imports matplotlib (models' pictures in :mod:`.models`, how a figure is
made and saved in :mod:`.figures`). It draws on :class:`matplotlib.figure.Figure` objects, not
through pyplot, so importing it switches no backend (a Jupyter session keeps its own). A ``plot_*``
saves a PNG at ``path`` (120 dpi, atomically: :mod:`modalctl.outdir`) and returns the path; one of a
single panel (:func:`plot_voltages`, :func:`plot_spectrogram`, :func:`plot_modes_needed`) given
``ax=`` draws on that Axes instead, writes nothing and returns it, so pictures compose::

    fig, (top, bottom) = plt.subplots(2, 1)  # in a notebook; or Figure().subplots(2, 1)
    plot_voltages(shot, ax=top)
    plot_spectrogram(shot, shot.focus_velocity, shot.plan.sample_rate, 0.024, ax=bottom)

Pictures of several panels are built from one-panel helpers (``_*_panel(ax, ...)``). Units as
labelled: mm, ms, kHz, V; velocities in mm/s, modal coefficients in m/s sqrt(kg).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from modalctl.model.metrics import Extremes
from modalctl.plan.decompose import Decomposition

from .figures import own_or_given as _own_or_given
from .figures import save as _save
from .figures import subplots as _subplots
from .models import plot_fe_convergence, plot_fe_shapes, plot_identification

__all__ = ["plot_decomposition", "plot_modes_needed", "plot_spacetime", "plot_modal_bars", "plot_voltages",
           "plot_spectrogram", "plot_learning", "write_run_report", "plot_loop", "plot_sweep_maps", "sweep_table",
           "plot_identification", "plot_fe_shapes", "plot_fe_convergence"]

NAMED_MODES = 10  # modes a closed loop's picture names in colour (plot_loop; the colour cycle's ten); the others grey
LABELLED_TICKS = 30  # mode labels an axis of modes carries at most (a tablet's 254 overlapped)


def _mode_ticks(ax, pos, labels) -> None:
    """The modes' labels under their bars: each up to :data:`LABELLED_TICKS` modes, then every few."""
    every = -(-len(labels) // LABELLED_TICKS)
    ax.set_xticks(pos[::every], [str(l) for l in labels[::every]], fontsize=7)


def _coefficients_panel(ax, dec: Decomposition):
    """|coefficient| of every mode (m/s sqrt(kg)), the kept ones in colour, the dropped in grey."""
    c = np.abs(dec.coefficients)
    kept = np.zeros(c.size, bool)
    kept[dec.modes_used] = True
    pos = np.arange(c.size)
    if not kept.all():
        ax.bar(pos[~kept], c[~kept], color="0.75", label="dropped")
    ax.bar(pos[kept], c[kept], color="C0", label="kept")
    _mode_ticks(ax, pos, dec.model.labels)
    ax.set_xlabel("mode")
    ax.set_ylabel("|coefficient| (m/s sqrt(kg))")
    ax.legend(frameon=False, loc="upper right")


def _reconstruction_panel(ax, dec: Decomposition):
    """A beam's reference field and its reduced reconstruction (mm/s over mm), the target zone shaded."""
    x = dec.model.grid.x * 1e3
    ax.fill_between(x, 0, 1, where=dec.shape.target_mask, transform=ax.get_xaxis_transform(),
                    color="C2", alpha=0.15, label="target zone")
    ax.plot(x, dec.shape.values * 1e3, "C3", lw=2, label="reference")
    ax.plot(x, dec.reconstruction * 1e3, "k--", lw=1.5, label=f"{dec.modes_used.size} modes")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("velocity at focus (mm/s)")
    ax.legend(frameon=False, fontsize=8)


def _plate_map_panel(ax, dec: Decomposition, data: np.ndarray, name: str, vmax: float):
    """A field (mm/s, colours -vmax to vmax) on a plate's lattice, the target zone outlined; its image."""
    grid = dec.model.grid
    nx, ny = grid.shape
    extent = [*grid.bounds[:, 0] * 1e3, *grid.bounds[:, 1] * 1e3]
    image = ax.imshow(data.reshape(ny, nx) * 1e3, origin="lower", extent=extent, cmap="RdBu_r", vmin=-vmax, vmax=vmax)
    ax.contour(dec.shape.target_mask.reshape(ny, nx), levels=[0.5], colors="k", linewidths=0.8, extent=extent)
    ax.set_title(name, fontsize=9)
    ax.set_xlabel("x (mm)")
    return image


def plot_decomposition(dec: Decomposition, path) -> Path:
    """Reference field, reduced reconstruction and target zone (a beam's curves, a plate's maps on
    its lattice with the error), over the modal coefficients."""
    m = dec.metrics()
    grid, ref, rec = dec.model.grid, dec.shape.values, dec.reconstruction
    title = (f"{dec.model.meta.get('name', 'model')}: {dec.modes_used.size} of {dec.model.n_modes} modes, "
             f"tau {m['tau']:.3f}, NRMSE {m['nrmse']:.3f}")
    if grid.dim == 1:
        fig, (top, bottom) = _subplots(2, 1, figsize=(8, 6.5), gridspec_kw={"height_ratios": [3, 2]})
        _reconstruction_panel(top, dec)
        top.set_title(title, fontsize=10)
        _coefficients_panel(bottom, dec)
    else:
        fig = Figure(figsize=(11, 6.5))
        axes = [fig.add_subplot(2, 3, i + 1) for i in range(3)]
        vmax = np.abs(ref).max() * 1e3
        for ax, data, name in zip(axes, [ref, rec, rec - ref], ["reference", "reduced model", "error"]):
            image = _plate_map_panel(ax, dec, data, name, vmax)
        axes[0].set_ylabel("y (mm)")
        fig.colorbar(image, ax=axes, label="velocity at focus (mm/s)", shrink=0.8)
        fig.suptitle(title, fontsize=10)
        _coefficients_panel(fig.add_subplot(2, 1, 2), dec)
    return _save(fig, path)


def plot_modes_needed(labels, series: dict, kept: dict, path=None, title: str = "", *, ax=None):
    """Max |coefficient| per mode (``labels``, k of them) of several pulse sets, with the kept band of each shaded:
    ``series`` maps a set's name to its largest relative |coefficient| over its centres, shape (k,), ``kept`` to the
    positional indices its rule keeps. Saved at ``path``, or drawn on ``ax`` (returned)."""
    fig, ax = _own_or_given(ax, path, (9, 4.5))
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
    return ax if fig is None else _save(fig, path)


def _window(shot, half: float = 4e-3):
    """The samples within ``half`` (s) of the focus time."""
    tf = shot.plan.focus_time
    return (shot.times >= tf - half) & (shot.times <= tf + half)


def _field_panel(ax, shot, finger=None):
    """A beam's velocity over x (mm) and T_F +- 4 ms; red off target above the margin, finger dotted."""
    grid, mask = shot.decomposition.model.grid, shot.decomposition.shape.target_mask
    tf, sel = shot.plan.focus_time, _window(shot)
    t, field = shot.times[sel], shot.field[:, sel]
    x = grid.x * 1e3
    vmax = np.max(np.abs(field)) * 1e3
    mesh = ax.pcolormesh((t - tf) * 1e3, x, field * 1e3, cmap="RdBu_r", vmin=-vmax, vmax=vmax, shading="auto")
    limit = shot.metrics.margin_criterion * np.max(np.abs(shot.focus_field))
    bad = (np.abs(field) > limit) & ~mask[:, None]
    ax.contourf((t - tf) * 1e3, x, bad.astype(float), levels=[0.5, 1.5], colors=["red"], alpha=0.8)
    ax.axhspan(x[mask].min(), x[mask].max(), color="C2", alpha=0.12, lw=0)
    ax.set_ylabel("x (mm)")
    if finger is not None:
        ax.axhline(finger[0] * 1e3, color="k", ls=":", lw=1.2)
        ax.annotate("finger", (1, finger[0] * 1e3), xycoords=("axes fraction", "data"), xytext=(-4, 3),
                    textcoords="offset points", ha="right", fontsize=8)
    ax.figure.colorbar(mesh, ax=ax, label="velocity (mm/s)")
    ax.set_title("field; red: off-target above the margin, green: target zone", fontsize=9)
    ax.set_xlabel("t - T_F (ms)")


def _extremes_panel(ax, shot, shade_window: bool = False):
    """The largest on- and off-target |w| (mm/s) over the shot, the margin's limit, the worst instant."""
    mask, m, tf = shot.decomposition.shape.target_mask, shot.metrics, shot.plan.focus_time
    whole = (shot.times - tf) * 1e3
    extremes = shot.extremes or Extremes.of(shot.field, mask)  # the shot's, measured once with its margin
    on, off = extremes.inside, extremes.outside
    ax.plot(whole, on * 1e3, "C2", lw=1, label="max |w| in target zone")
    ax.plot(whole, off * 1e3, "C0", lw=1, label="max |w| off target")
    limit = m.margin_criterion * np.max(np.abs(shot.focus_field))
    ax.axhline(limit * 1e3, color="red", ls="--", lw=1, label=f"margin {m.margin_criterion:g} x focus peak")
    worst = int(np.argmax(off))
    ax.plot(whole[worst], off[worst] * 1e3, "kx", label=f"worst off target ({whole[worst]:+.2f} ms)")
    if shade_window:
        t = shot.times[_window(shot)]
        ax.axvspan((t[0] - tf) * 1e3, (t[-1] - tf) * 1e3, color="0.9", lw=0, zorder=0, label="left: T_F +- 4 ms")
    ax.set_ylabel("velocity (mm/s)")
    ax.legend(frameon=False, fontsize=8)
    ax.set_xlabel("t - T_F (ms)")


def plot_spacetime(shot, path, finger=None) -> Path:
    """Space-time field around the focus with margin violations in red (thesis Figs 5.3-5.5), beside
    the largest on- and off-target |w| over the whole shot (where the margin is measured): a beam's
    over x and T_F +- 4 ms, a plate's in frames around T_F (a lattice grid). ``finger``: where a
    finger rests (m, a point), marked on the field."""
    m, grid = shot.metrics, shot.decomposition.model.grid
    title = (f"margin ratio {m.margin_ratio:.2f} (criterion {m.margin_criterion:g}, "
             f"{'met' if m.margin_ok else 'NOT met'}), tau {m.tau:.3f}")
    if finger is not None:
        title += f"; a finger rests at {', '.join(f'{1e3 * v:g}' for v in finger)} mm"
    fig, (left, right) = _subplots(1, 2, figsize=(12, 4.8), gridspec_kw={"width_ratios": [3, 2]})
    if grid.dim == 1:
        _field_panel(left, shot, finger)
        _extremes_panel(right, shot, shade_window=True)
    else:
        _extremes_panel(left, shot)
        right.axis("off")
        if grid.shape is not None:
            _plate_frames(fig, right, shot, finger)
    fig.suptitle(title, fontsize=10)
    return _save(fig, path)


FRAMES_MS = (-2.0, -1.0, 0.0, 1.0)  # a plate's field drawn at these times from the focus


def _plate_frame_panel(ax, shot, sample: int, dt: float, vmax: float, finger=None):
    """A plate's field (mm/s) at ``sample``, ``dt`` (ms) from T_F, a resting finger marked; its image."""
    grid, mask = shot.decomposition.model.grid, shot.decomposition.shape.target_mask
    x, y = grid.points.T * 1e3
    shape = grid.shape[::-1]
    image = np.ma.masked_where(grid.mass == 0, shot.field[:, sample] * 1e3).reshape(shape)
    drawn = ax.imshow(image, origin="lower", extent=(x.min(), x.max(), y.min(), y.max()), cmap="RdBu_r", vmin=-vmax,
                      vmax=vmax)
    ax.contour(x.reshape(shape), y.reshape(shape), mask.reshape(shape).astype(float), levels=[0.5], colors="C2",
               linewidths=0.8)
    if finger is not None and len(finger) == 2:
        ax.plot(finger[0] * 1e3, finger[1] * 1e3, "k+", ms=6)
    ax.set_title(f"T_F {dt:+g} ms", fontsize=8)
    ax.tick_params(labelsize=6)
    ax.set_aspect("equal")
    return drawn


def _plate_frames(fig, where, shot, finger=None) -> None:
    """The plate's field at ``FRAMES_MS`` from T_F, one colour scale, in a 2 x 2 grid in ``where``."""
    tf = shot.plan.focus_time
    samples = [int(np.argmin(np.abs(shot.times - (tf + dt * 1e-3)))) for dt in FRAMES_MS]
    vmax = np.max(np.abs(shot.field[:, samples])) * 1e3
    cells = where.get_subplotspec().subgridspec(2, 2, hspace=0.35, wspace=0.1)
    frames = [fig.add_subplot(cells[k // 2, k % 2]) for k in range(len(samples))]
    for ax, sample, dt in zip(frames, samples, FRAMES_MS):
        image = _plate_frame_panel(ax, shot, sample, dt, vmax, finger)
    fig.colorbar(image, ax=frames, label="velocity (mm/s)", shrink=0.8)


def _focus_profile_panel(ax, shot):
    """A beam's velocity at T_F over x (mm/s over mm): reference, reduced model, measured."""
    x = shot.decomposition.model.grid.x * 1e3
    ax.plot(x, shot.decomposition.shape.values * 1e3, "C3", lw=2, label="reference")
    ax.plot(x, shot.decomposition.reconstruction * 1e3, "k--", lw=1.2, label="reduced model")
    ax.plot(x, shot.focus_field * 1e3, "C0", lw=1.2, label="measured")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("velocity at T_F (mm/s)")
    ax.legend(frameon=False, fontsize=8)


def _modal_coefficients_panel(ax, shot):
    """Each mode's coefficient at T_F (m/s sqrt(kg)): reference, reduced, measured side by side."""
    coeffs, labels = shot.coefficients(), shot.decomposition.model.labels
    pos = np.arange(len(labels))
    for i, (name, colour) in enumerate([("reference", "C3"), ("reduced", "k"), ("measured", "C0")]):
        ax.bar(pos + (i - 1) * 0.27, coeffs[name], 0.27, color=colour, label=name)
    _mode_ticks(ax, pos, labels)
    ax.set_xlabel("mode")
    ax.set_ylabel("coefficient (m/s sqrt(kg))")
    ax.axhline(0, color="0.5", lw=0.5)
    ax.legend(frameon=False, fontsize=8, loc="upper right")  # "best" searched a tablet's 762 bars


def plot_modal_bars(shot, path) -> Path:
    """Each mode's coefficient at T_F, reference, reduced and measured (thesis Fig 4.17), under a beam's field then
    (a plate's field at T_F is :func:`plot_spacetime`'s)."""
    if shot.decomposition.model.grid.dim == 1:
        fig, (top, bottom) = _subplots(2, 1, figsize=(9, 6.5), gridspec_kw={"height_ratios": [2, 3]})
        _focus_profile_panel(top, shot)
    else:
        fig, bottom = _subplots(1, 1, figsize=(9, 4))
        top = bottom
    _modal_coefficients_panel(bottom, shot)
    m = shot.metrics
    top.set_title(f"tau {m.tau:.3f} (model {m.tau_model:.3f}), tau_norm {m.tau_norm:.3f}, "
                  f"NRMSE {m.nrmse:.3f}", fontsize=10)
    return _save(fig, path)


def plot_voltages(shot, path=None, *, ax=None):
    """Drive voltage (V) of each active actuator over the shot (ms), T_F dotted; saved at ``path`` or on ``ax``."""
    fig, ax = _own_or_given(ax, path, (9, 4))
    cap = shot.capture
    active = np.flatnonzero(np.max(np.abs(cap.voltages), axis=1) > 0)
    for a in active:
        ax.plot(cap.times * 1e3, cap.voltages[a], lw=0.6, label=f"actuator {a + 1}")
    ax.axvline(shot.plan.focus_time * 1e3, color="k", ls=":", lw=1, label="T_F")
    ax.set_xlabel("t (ms)")
    ax.set_ylabel("voltage (V)")
    ax.set_title(f"peak {shot.metrics.peak_voltage:.1f} V", fontsize=10)
    ax.legend(frameon=False, fontsize=7, ncol=4)
    return ax if fig is None else _save(fig, path)


def plot_spectrogram(shot, velocity: np.ndarray, sample_rate: float, where: float, path=None, *, ax=None):
    """Spectrogram of the velocity at the focus point (thesis Fig 4.29), with the kept resonances:
    ``velocity`` (m/s) sampled at ``sample_rate`` (Hz) at ``where`` (m, for the title); saved at
    ``path``, or drawn on ``ax`` (returned) with its colour bar beside."""
    from scipy.signal import spectrogram

    fig, ax = _own_or_given(ax, path, (9, 4.5))
    nper = int(2 ** np.round(np.log2(sample_rate / 400)))  # about 400 Hz resolution, 2.5 ms windows
    f, t, s = spectrogram(velocity, sample_rate, nperseg=nper, noverlap=nper * 7 // 8)
    model = shot.decomposition.model
    keep = f <= 1.3 * np.max(model.frequencies[shot.plan.modes])
    db = 10 * np.log10(s[keep] + 1e-30)
    mesh = ax.pcolormesh(t * 1e3, f[keep] / 1e3, db, shading="auto", vmin=db.max() - 60, vmax=db.max())
    for fk in model.frequencies[shot.plan.modes]:
        ax.axhline(fk / 1e3, color="w", lw=0.4, ls=":")
    ax.axvline(shot.plan.focus_time * 1e3, color="r", lw=0.8)
    ax.set_xlabel("t (ms)")
    ax.set_ylabel("frequency (kHz)")
    ax.set_title(f"velocity at x = {where * 1e3:.1f} mm (dotted: kept resonances, red: T_F)", fontsize=10)
    ax.figure.colorbar(mesh, ax=ax, label="dB (m/s)^2/Hz")
    return ax if fig is None else _save(fig, path)


def plot_learning(learned, labels, path) -> Path:
    """What a learning shot taught (:class:`modalctl.run.LearningMetrics`): each mode's resonance
    and damping relative to the model it was planned on, with two standard errors where a record's
    fit gives them, and the common shift; the modes of the shot drawn in colour, the others (seen
    less, held near the common change by the prior, or moved by the tracked ones) in grey."""
    shift = 100 * np.asarray(learned.relative_shift)
    f = np.asarray(learned.frequencies_hz)
    fitted = learned.frequency_error_hz is not None
    f_error = 200 * np.asarray(learned.frequency_error_hz) / (f / (1 + shift / 100)) if fitted else None
    pos = np.arange(shift.size)
    used = np.isin(np.asarray(labels), learned.modes_used)
    fig, (top, bottom) = _subplots(2, 1, figsize=(9, 6), sharex=True)
    for mask, colour, name in ((used, "C0", "modes of the shot"), (~used, "0.6", "other modes")):
        top.errorbar(pos[mask], shift[mask], yerr=f_error[mask] if fitted else None, fmt="o", color=colour,
                     capsize=3, label=name)
    common = 100 * learned.common_shift
    if learned.common_shift_error is not None:
        error = 100 * learned.common_shift_error
        top.axhspan(common - 2 * error, common + 2 * error, color="C3", alpha=0.15)
        top.axhline(common, color="C3", lw=1, label=f"common shift {common:+.2f}% (+-{2 * error:.2f}%)")
    else:
        top.axhline(common, color="C3", lw=1, label=f"median shift of the tracked modes {common:+.2f}%")
    top.axhline(0, color="k", lw=0.5)
    top.set_ylabel("resonance change (%)")
    top.legend(frameon=False, fontsize=8)
    change = np.asarray(learned.relative_damping_change)
    z_error = 200 * np.asarray(learned.damping_error) / (np.asarray(learned.damping) / (1 + change)) if fitted \
        else None
    for mask, colour in ((used, "C0"), (~used, "0.6")):
        bottom.errorbar(pos[mask], 100 * change[mask], yerr=z_error[mask] if fitted else None, fmt="o",
                        color=colour, capsize=3)
    bottom.axhline(100 * learned.common_damping_change, color="C3", lw=1,
                   label=f"{'common change' if fitted else 'median change of the tracked modes'} "
                         f"{100 * learned.common_damping_change:+.0f}%")
    bottom.axhline(0, color="k", lw=0.5)
    bottom.set_ylabel("damping change (%)")
    bottom.legend(frameon=False, fontsize=8)
    bottom.set_xticks(pos, [str(l) for l in labels], fontsize=7)
    bottom.set_xlabel("mode")
    how = (f"its record: 2 standard errors, fit {learned.update_seconds:.1f} s" if fitted
           else "a pole tracker during it")
    top.set_title(f"learned from the first shot (tau {learned.tau:.3f}, margin {learned.margin_ratio:.3f}), "
                  f"from {how}", fontsize=10)
    return _save(fig, path)


def write_run_report(shot, out, chosen=None) -> dict:
    """The pictures of a run (a :class:`modalctl.run.ShotResult`), or those whose name ``chosen(name)``
    accepts, into directory ``out`` (the loop's from its ``log.json`` there); returns {name: path}. A
    finger the device says rests on the structure is drawn where it rests."""
    out, finger = Path(out), shot.metrics.device_info.get("finger_at_m")
    where = float(shot.decomposition.model.grid.points[shot.focus_point, 0])
    draw = {"spacetime": lambda: plot_spacetime(shot, out / "spacetime.png", finger),
            "modal_bars": lambda: plot_modal_bars(shot, out / "modal_bars.png"),
            "voltages": lambda: plot_voltages(shot, out / "voltages.png"),
            "spectrogram": lambda: plot_spectrogram(shot, shot.focus_velocity, shot.plan.sample_rate, where,
                                                    out / "spectrogram.png"),
            "learning": lambda: plot_learning(shot.learning, shot.decomposition.model.labels, out / "learning.png"),
            "loop": lambda: plot_loop(out / "log", out / "loop.png")}
    drawn = {"learning": shot.learning is not None, "loop": shot.loop is not None and (out / "log.json").exists()}
    return {k: str(f()) for k, f in draw.items() if drawn.get(k, True) and (chosen is None or chosen(k))}


def plot_loop(log, path) -> Path:
    """A closed-loop run from its log: each mode's envelope, planned (reference) and measured, and
    the feedback command against the time; the fault, if any, marked. With more than
    :data:`NAMED_MODES` modes, the ten of the largest planned envelopes are named in colour and the
    others drawn thin and grey: a legend of a plate's 50 modes hid the curves, a tablet's 254 took
    3.7 s to place."""
    from modalctl.loops.recorder import read_log

    records, header = read_log(log)
    meta = header["meta"]
    t = (records["period"] + 1) / meta["control_rate_hz"] * 1e3
    reference, measured, command = (np.abs(records[name]) for name in ("reference", "measured", "command"))
    k = reference.shape[1]
    named = np.sort(np.argsort(-reference.max(axis=0, initial=0.0))[:NAMED_MODES])
    fig, axes = _subplots(2, 1, figsize=(10, 6.5), sharex=True)
    others = np.setdiff1d(np.arange(k), named)
    if others.size:  # one collection per panel: a line per mode cost 0.3 s a hundred modes
        grey = {"color": "0.75", "lw": 0.5}
        axes[0].plot(t, reference[:, others], **grey)
        axes[0].plot(t, measured[:, others], ls="--", **grey)
        axes[1].plot(t, command[:, others], **grey)
    for i in named:
        line, = axes[0].plot(t, reference[:, i], lw=0.9, label=f"mode {meta['modes'][i]}")
        axes[0].plot(t, measured[:, i], lw=0.7, ls="--", color=line.get_color())
        axes[1].plot(t, command[:, i], lw=0.8, color=line.get_color())
    axes[0].set(ylabel="|envelope| (m/s)", title="per-mode envelopes: reference (solid) and measured (dashed)"
                + (f"; the {others.size} modes of smaller references in grey" if others.size else ""))
    axes[0].legend(fontsize=7, ncol=4, loc="upper left")
    axes[1].set(xlabel="time (ms)", ylabel="|feedback command| (modal force)",
                title="feedback commands (the loops', within their authority, and what a touch or a drift is given "
                      "back)")
    failed = np.flatnonzero(records["state"] == 3)
    for ax in axes:
        for n in failed:
            ax.axvline(t[n], color="r", lw=1)
    if failed.size:
        axes[0].text(t[failed[0]], axes[0].get_ylim()[1] * 0.9, " fault: outputs ramped to zero", color="r")
    return _save(fig, path)


_AXIS_LABELS = {"drift": "drift (%)", "damping_error": "damping error (%)", "finger": "finger damping (N s/m)",
                "latency": "extra latency (periods)", "snr_db": "SNR (dB)", "focus_time": "focus time (ms)",
                "seed": "seed"}
_AXIS_SCALE = {"drift": 100, "damping_error": 100, "focus_time": 1e3}


def sweep_table(rows, axes) -> str:
    """Markdown: one row per scenario (``rows`` of a sweep, swept over the fields ``axes``), tau
    (margin ratio) of each method side by side."""
    methods = list(dict.fromkeys(r["method"] for r in rows))
    by = {(r["method"], *(r[a] for a in axes)): r for r in rows}
    keys = sorted({tuple(r[a] for a in axes) for r in rows})
    head = [_AXIS_LABELS.get(a, a) for a in axes] + [f"{m}: tau (margin)" for m in methods]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for key in keys:
        cells = [f"{v * _AXIS_SCALE.get(a, 1):g}" for a, v in zip(axes, key)]
        for m in methods:
            r = by.get((m, *key))
            cells.append("" if r is None else "refused" if r["state"] == "refused" else
                         f"{r['tau']:.3f} ({r['margin_ratio']:.2f})" + ("" if r["state"] != "error" else " stopped"))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _sweep_panel(ax, rows, axes, method: str, criterion: tuple):
    """One method's ``criterion`` (metric, good, label) over the swept ``axes``: a map (two) or a curve."""
    metric, good, label = criterion
    x_name = axes[0]
    xs = sorted({r[x_name] for r in rows})
    ys = sorted({r[axes[1]] for r in rows}) if len(axes) == 2 else [None]
    table = np.full((len(ys), len(xs)), np.nan)  # a refused case (no metric) stays nan: blank, said so
    for r in (r for r in rows if r["method"] == method and r[metric] is not None):
        table[ys.index(r[axes[1]]) if len(axes) == 2 else 0, xs.index(r[x_name])] = r[metric]
    if len(axes) == 2:
        image = ax.imshow(table, origin="lower", aspect="auto", cmap="RdYlGn" if metric == "tau" else "RdYlGn_r",
                          vmin=0.5 if metric == "tau" else 0.3, vmax=1.0)
        for i in range(len(ys)):
            for j in range(len(xs)):
                ok = table[i, j] >= good if metric == "tau" else table[i, j] <= good
                ax.text(j, i, "refused" if np.isnan(table[i, j]) else f"{table[i, j]:.3f}" + ("" if ok else "\n✗"),
                        ha="center", va="center", fontsize=8)
        ax.set_xticks(range(len(xs)), [f"{v * _AXIS_SCALE.get(x_name, 1):g}" for v in xs])
        ax.set_yticks(range(len(ys)), [f"{v * _AXIS_SCALE.get(axes[1], 1):g}" for v in ys])
        ax.set_ylabel(_AXIS_LABELS.get(axes[1], axes[1]))
        ax.figure.colorbar(image, ax=ax, shrink=0.8)
    else:
        ax.plot(np.array(xs) * _AXIS_SCALE.get(x_name, 1), table[0], "o-")
        ax.axhline(good, color="k", ls=":", lw=0.8)
        ax.set_ylabel(label)
    ax.set_xlabel(_AXIS_LABELS.get(x_name, x_name))
    ax.set_title(f"{method}: {label} (" + ("at least" if metric == "tau" else "at most") + f" {good:g})")


def plot_sweep_maps(rows, axes, methods, path) -> Path:
    """tau and margin ratio of each method (a column each) over one or two swept parameters: maps
    (two) or curves (one)."""
    fig, grid = _subplots(2, len(methods), figsize=(4.2 * len(methods), 7.2), squeeze=False, layout="constrained")
    for col, method in enumerate(methods):
        for row, criterion in enumerate((("tau", 0.95, "tau"), ("margin_ratio", 0.5, "margin ratio"))):
            _sweep_panel(grid[row, col], rows, axes, method, criterion)
    plans = sorted({f"{r.get('scene', '?')}: {r.get('planner', '?')} planner, margin {r.get('margin') or 'none'}"
                    for r in rows})
    fig.suptitle(f"where each method fails (✗: criterion not met); {'; '.join(plans)}")
    return _save(fig, path)
