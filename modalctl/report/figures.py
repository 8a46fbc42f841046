"""How the pictures are made: on :class:`matplotlib.figure.Figure` objects, not through pyplot (importing
them switches no backend), saved as PNGs atomically (:mod:`modalctl.outdir`)."""

from __future__ import annotations

from pathlib import Path

from matplotlib.figure import Figure

from modalctl.outdir import atomic

__all__ = ["save", "subplots", "own_or_given", "PNG_LEVEL"]

#: zlib's level for the PNGs (PIL's default 6): the tablet's 255 mode shapes (1560 x 2274 pixels) encode in
#: 0.48 s at 1, 1.47 s at 6, for 5% more bytes; a picture is written once and read by a person
PNG_LEVEL = 1


def save(fig: Figure, path, dpi: int = 120, tight: bool = True) -> Path:
    """``fig`` as a PNG at ``path`` (120 dpi, cropped to what is drawn unless not ``tight``), written atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic(path) as temporary:  # a link planted under that name is replaced, not followed
        fig.savefig(temporary, dpi=dpi, bbox_inches="tight" if tight else None,
                    pil_kwargs={"compress_level": PNG_LEVEL})
    return path


def subplots(nrows: int = 1, ncols: int = 1, *, figsize, layout=None, **kw):
    """A new :class:`Figure` (``figsize`` in inches) and its grid of Axes, as pyplot's subplots."""
    fig = Figure(figsize=figsize, layout=layout)
    return fig, fig.subplots(nrows, ncols, **kw)


def own_or_given(ax, path, figsize):
    """``(fig, ax)`` of a one-panel picture: the caller's Axes (``fig`` None), or a new figure's."""
    if ax is None and path is None:
        raise ValueError("give path (where to save the picture) or ax (where to draw it)")
    return (None, ax) if ax is not None else subplots(figsize=figsize)
