"""Where the convex planner checks the margin: :class:`Cover`, the off-target grid points as nested
boxes, each with a proven bound on the field over its points, so that the field is computed only
where the margin may be at stake (its class notes say what the bound guarantees)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Cover"]

LEAF = 64  # points in a cover's smallest boxes at most: where the bound is not enough, their field, exactly
SPLITS = 5  # halvings from a box to its children (32 children)
COMPONENTS = 4  # the leading components of what a box's affine fit leaves, bounded apart (benchmarks/margin_check.py)
OVERSAMPLE = 4  # the components' randomized range finder's extra directions
CHUNK = 4096  # samples of the field's bound at once (its memory: the boxes' few rows times this)
SLACK = 1e-10  # the bound's allowance for round-off, relative to sum_k max_i |phi_k(x_i)| |eta'_k|


@dataclass(eq=False)
class _Box:
    """Points ``start:stop`` of a :class:`Cover`'s order, and what bounds the field on each of its
    children: the rows ``fit`` ((1 + d + J) c, K: every child's affine fit's value at the centre of its
    points' span, then its slope along each axis times the span's half-width, then the J leading
    components of what the fit leaves, each times its largest size on the points) and the largest
    residuals left ``residual`` (c, K)."""

    start: int
    stop: int
    children: tuple = ()
    fit: np.ndarray | None = None
    residual: np.ndarray | None = None
    affine: int = 0  # the affine fit's rows (1 + d) among a child's first rows

    def __post_init__(self):
        if self.fit is not None:  # the search's single-precision copies, a column per row of fit
            self._fit32 = np.ascontiguousarray(self.fit.T, np.float32)
            self._residual32 = np.ascontiguousarray(self.residual.T, np.float32)

    def bounds(self, velocity: np.ndarray, speed: np.ndarray) -> np.ndarray:
        """Each child's bound on ``|w|`` over its points at each sample of ``velocity`` (s, K: a row per
        sample) (``speed``: its absolute value), shape (s, c): ``|A| + sum_d |B_d| h_d + sum_j |C_j| + R .
        speed``, the affine part's largest size over the span (centre ``A``, each axis's slope times
        half-width ``B_d h_d``), the residuals' leading components' ``C_j`` and the rest's: one product and
        an absolute value, the rows folded so when the box was built. In single
        precision for single-precision samples (what :class:`Cover`'s search adds for it: its notes)."""
        single = velocity.dtype == np.float32
        fit, residual = (self._fit32, self._residual32) if single else (self.fit.T, self.residual.T)
        return self._summed(velocity @ fit, speed @ residual)

    def rough(self, velocity: np.ndarray) -> np.ndarray:
        """The largest of the children's affine parts' sizes over their spans (``|A| + sum_d |B_d| h_d``)
        at each column of ``velocity`` (K, s), shape (s,): not a bound (their residuals left out) but a
        ranking of the columns by the field's size, in single precision (a copy of them: twice as fast
        as the double product; the columns it ranks first are then computed exactly)."""
        single = np.ascontiguousarray(velocity.T, np.float32)
        c = len(self.children)
        return self._summed(single @ self._fit32[:, c:self.affine * c], np.abs(single @ self._fit32[:, :c])).max(axis=1)

    def _summed(self, affine: np.ndarray, residual: np.ndarray) -> np.ndarray:
        """:meth:`bounds` from the rows' products (s, r c) and the residuals' (s, c): the latter (in place)
        with the size of each of the r rows' added."""
        c = len(self.children)
        size = np.abs(affine)
        for first in range(0, size.shape[1], c):  # the rows' blocks added in place: numpy's sum over a middle
            residual += size[:, first:first + c]  # axis took a third of a search
        return residual

    def terms(self) -> np.ndarray:
        """Each child's ``sum over the fit's rows of |row_k| + R_k`` (c, K): what multiplies ``|eta'_k|``
        in a bound of the round-off of :meth:`bounds`."""
        c = len(self.children)
        return np.abs(self.fit).reshape(-1, c, self.fit.shape[1]).sum(axis=0) + self.residual


class Cover:
    """The off-target grid points as nested boxes, with a bound on the field over each box's points
    that is proven, not sampled.

    A box (its points halved at the median along its longer side, five times over to its 32
    children, down to :data:`LEAF` points) fits every mode affinely over its own points and keeps
    about the leading :data:`COMPONENTS` of what the fits leave (of the singular value decomposition of
    the residuals, points by modes: :func:`_leading`),
    ``phi_k(x_i) = a_k + b_k . (x_i - x_B) + sum_j u_ij v_jk + r_ik``, then ``R_k = max_i |r_ik|``
    over the points, ``U_j = max_i |u_ij|`` and the span ``[low, high]`` of ``x_i - x_B``. At a
    sample with modal velocities ``eta'_k``, with ``A = sum_k a_k eta'_k``, ``B = sum_k b_k eta'_k``
    and ``V_j = sum_k v_jk eta'_k``, every point ``i`` of the box has

        ``|w(x_i)| = |A + B . (x_i - x_B) + sum_j u_ij V_j + sum_k r_ik eta'_k|
                   <= max(A + max_d B . d, -(A + min_d B . d)) + sum_j U_j |V_j| + sum_k R_k |eta'_k|``

    (``d`` over the span: the affine part's extremes are at its corners). Summed mode by mode, the
    residuals' bound was most of a box's (on the panel's closed-loop check, 2.3 times the box's
    largest field, where the affine part's bound is 0.86 of it); the components, a few shapes the
    modes' residuals share, are summed J times instead of K times. The whole set's bound
    is ``sum_k max_i |phi_k(x_i)| |eta'_k|``. **What it guarantees**: for every off-target grid
    point and every sample, ``|w(x_i, t_n)|`` is at most the bound of every box that holds the
    point (the residuals and spans are the points' own, so nothing is assumed about the modes'
    smoothness; :data:`SLACK` of the whole set's bound is added for round-off, and what the search's
    single precision may lose, proven a priori: :func:`_single_rounding`). It says nothing
    of the surface between grid points, which the model does not describe. A search goes down
    the boxes only where their bound exceeds the level asked, at the samples where it does; the
    field is computed, by BLAS, only on the smallest boxes reached, at those samples: on a panel of
    8,000 off-target points a few per cent of the points-by-samples the whole grid would take.

    Parameters
    ----------
    shapes : ndarray, shape (K, n)
        Every mode's value at each of the points.
    points : ndarray, shape (n, d)
        Their coordinates (m), d = 1 or 2.
    leaf : int
        Points in the smallest boxes at most.
    splits : int
        Halvings from a box to its children (``2 ** splits`` children).
    components : int
        The residuals' leading components each box's bound keeps apart (J).
    """

    def __init__(self, shapes: np.ndarray, points: np.ndarray, leaf: int = LEAF, splits: int = SPLITS,
                 components: int = COMPONENTS):
        shapes, points = np.asarray(shapes, float), np.asarray(points, float)
        points = points[:, None] if points.ndim == 1 else points
        self.leaf, self.splits, self.components = int(leaf), int(splits), int(components)
        self.reach = np.abs(shapes).max(axis=1) if shapes.size else np.zeros(shapes.shape[0])  # (K,)
        order = []
        self.root = self._build(np.arange(shapes.shape[1]), shapes, points, order)
        self.order = np.concatenate([o[0] for o in order]) if order else np.zeros(0, int)  # position -> point
        self.values = np.ascontiguousarray(shapes[:, self.order].T)  # (n, K), each box's points contiguous
        self.neighbours = _neighbours(points)  # (n, deg), in the given order; n pads
        self.slack = SLACK + _single_rounding(self.root, self.reach)  # of the whole set's bound (class notes)

    @property
    def size(self) -> int:
        return self.order.size

    def _build(self, idx: np.ndarray, shapes, points, order: list) -> _Box:
        start = order[-1][1] if order else 0
        if idx.size <= self.leaf:
            order.append((idx, start + idx.size))
            return _Box(start, start + idx.size)
        parts = [idx]
        for _ in range(self.splits):
            parts = [half for p in parts for half in (_halves(p, points) if p.size > self.leaf else (p,))]
        children = tuple(self._build(p, shapes, points, order) for p in parts)
        fits = [_bounding_rows(shapes[:, p], points[p], self.components) for p in parts]
        fit = np.concatenate([np.stack([f[0][j] for f in fits]) for j in range(fits[0][0].shape[0])])
        return _Box(start, start + idx.size, children, fit, np.stack([f[1] for f in fits]), 1 + points.shape[1])

    def _descend(self, box: _Box, state, slack, cols, floor: float, leaf, pruned, exact) -> None:
        """Down from ``box`` at the samples ``cols`` whose bound on it exceeds ``floor``: ``leaf(box,
        cols, field)`` on the smallest boxes reached (``field`` (points, samples) from ``exact[cols]``,
        the velocities (N, K) in double precision, a row per sample), ``pruned(cols, bound)`` with the largest bound of
        the children it stops at (-inf where none). ``state`` (s, 2K), single precision: a row per
        sample, its modal velocities then their sizes: a descent gathers the rows it keeps, the search's
        main cost (a tablet's 254 modes: its samples as columns of double precision, a gather along
        rows each, took 1.7 of the 2.8 s of a search, the products 1.0 s)."""
        k = self.values.shape[1]
        if not box.children:
            leaf(box, cols, self.values[box.start:box.stop] @ exact[cols].T)
            return
        bounds = box.bounds(state[:, :k], state[:, k:])
        bounds += slack[:, None]
        overs = bounds > np.float64(floor)  # not floor rounded to single precision (a Python float would be)
        counts = np.count_nonzero(overs, axis=0).tolist()  # each child's samples over: one call, not two a child
        if pruned is not None and min(counts) < cols.size:
            pruned(cols, np.where(overs, -np.inf, bounds).max(axis=1))
        for child, over, count in zip(box.children, np.ascontiguousarray(overs.T), counts):
            if count == cols.size:
                self._descend(child, state, slack, cols, floor, leaf, pruned, exact)
            elif count:
                self._descend(child, state[over], slack[over], cols[over], floor, leaf, pruned, exact)

    @staticmethod
    def _state(velocity: np.ndarray) -> np.ndarray:
        """``velocity`` (K, s) as :meth:`_descend` searches it: (s, 2K), single precision, each sample's
        velocities then their sizes."""
        single = velocity.T.astype(np.float32)
        return np.ascontiguousarray(np.hstack([single, np.abs(single)]))

    def top(self, velocity: np.ndarray, floor: float = 0.0) -> np.ndarray:
        """The largest ``|w|`` over the points at each column of ``velocity`` (K, N), shape (N,):
        exact (to round-off) wherever it exceeds ``floor``; elsewhere a bound on it, at most
        ``floor``, stands in."""
        velocity = np.asarray(velocity, float)
        out = np.zeros(velocity.shape[1])
        if self.size == 0:
            return out
        for first in range(0, velocity.shape[1], CHUNK):
            v = velocity[:, first:first + CHUNK]
            speed = np.abs(v)
            whole = self.reach @ speed
            top = out[first:first + CHUNK]
            top[:] = whole
            near = np.flatnonzero(whole > floor)
            if near.size == 0:
                continue
            top[near] = 0.0

            def leaf(box, cols, field, top=top):
                top[cols] = np.maximum(top[cols], np.abs(field).max(axis=0))

            def pruned(cols, bound, top=top):
                top[cols] = np.maximum(top[cols], bound)

            self._descend(self.root, self._state(v[:, near]), self.slack * whole[near], near, floor, leaf, pruned,
                          np.ascontiguousarray(v.T))
        return out

    def largest(self, velocity: np.ndarray) -> float:
        """The largest ``|w|`` over every point and column of ``velocity`` (K, N), exactly: the field
        on every point at the few columns whose bound is largest gives a floor, and :meth:`top`
        above it the rest."""
        velocity = np.asarray(velocity, float)
        if self.size == 0 or velocity.shape[1] == 0:
            return 0.0
        if not self.root.children:  # a few points
            return float(np.abs(self.values @ velocity).max())
        found = self.at_least(velocity)
        return max(found, float(self.top(velocity, found).max()))

    def at_least(self, velocity: np.ndarray, columns: int = 8) -> float:
        """A value the largest ``|w|`` over the points and columns of ``velocity`` (K, N) reaches:
        the field on every point at the ``columns`` columns whose bound is largest."""
        velocity = np.asarray(velocity, float)
        if self.size == 0 or velocity.shape[1] == 0:
            return 0.0
        if not self.root.children:
            rough = self.reach @ np.abs(velocity)
        else:
            rough = np.concatenate([self.root.rough(velocity[:, i:i + CHUNK])
                                    for i in range(0, velocity.shape[1], CHUNK)])
        return float(np.abs(self.values @ velocity[:, np.argsort(rough)[-columns:]]).max())

    def lobes(self, size: np.ndarray, level: float) -> np.ndarray:
        """The points where ``size`` (n,: a field's absolute value, in the points' order) exceeds
        ``level`` and is at least its value at each of the point's neighbours (along a line, the
        points before and after; on a plate, those within 1.5 grid spacings): each lobe's crest."""
        above = np.flatnonzero(size > level)
        padded = np.append(size, -np.inf)
        return above[size[above] >= padded[self.neighbours[above]].max(axis=1)]

    def field(self, velocity: np.ndarray, floor: float = 0.0) -> np.ndarray:
        """The field at each column of ``velocity`` (K, s) on every point (in their given order),
        shape (n, s): exact wherever the bound exceeds ``floor`` (every point whose ``|w|`` does),
        zero elsewhere. Ask for a few columns at a time: it is the points-by-columns array."""
        velocity = np.asarray(velocity, float)
        out = np.zeros((self.size, velocity.shape[1]))
        if self.size == 0 or velocity.shape[1] == 0:
            return out
        speed = np.abs(velocity)
        whole = self.reach @ speed
        near = np.flatnonzero(whole > floor)

        def leaf(box, cols, field):
            out[box.start:box.stop, cols] = field

        if near.size:
            self._descend(self.root, self._state(velocity[:, near]), self.slack * whole[near], near, floor, leaf, None,
                          np.ascontiguousarray(velocity.T))
        result = np.empty_like(out)
        result[self.order] = out
        return result


def _single_rounding(root: _Box, reach: np.ndarray) -> float:
    """The most :meth:`_Box.bounds` in single precision may lose to round-off, relative to the whole set's
    bound ``sum_k reach_k |eta'_k|``: each of its sums of n = K + 5 + r terms (the products, the inputs'
    rounding, the absolute values' of its r rows and the residual's sums) is within ``gamma_n = n u / (1 -
    n u)`` of its terms' sizes (u = 2^-24; Higham, Accuracy and Stability of Numerical Algorithms, 3.1), and
    the terms of a box's bound are ``terms_k |eta'_k|`` (:meth:`_Box.terms`), at most the largest ``terms_k
    / reach_k`` of any box times the whole set's."""
    rows = root.fit.shape[0] // len(root.children) if root.children else 0
    n = reach.size + 5 + rows
    u = float(np.finfo(np.float32).eps) / 2
    largest, stack = 0.0, [root]
    while stack:
        box = stack.pop()
        if box.children:
            stack.extend(box.children)
            terms, seen = box.terms(), reach > 0  # a mode zero on every point is fitted by zeros, exactly
            largest = max(largest, float((terms[:, seen] / reach[seen]).max(initial=0.0)))
    return n * u / (1 - n * u) * largest


def _neighbours(points: np.ndarray) -> np.ndarray:
    """Each point's neighbours, shape (n, deg), padded with n: along a line the points before and
    after it in their order; on a plate the points within 1.5 times the grid's median spacing."""
    n = points.shape[0]
    if points.shape[1] == 1 or n < 3:
        index = np.arange(n)
        return np.stack([np.where(index > 0, index - 1, n), np.where(index < n - 1, index + 1, n)], axis=1)
    from scipy.spatial import cKDTree

    tree = cKDTree(points)
    spacing = float(np.median(tree.query(points, k=2)[0][:, 1]))
    pairs = tree.query_pairs(1.5 * spacing, output_type="ndarray")
    pairs = np.vstack([pairs, pairs[:, ::-1]])
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    counts = np.bincount(pairs[:, 0], minlength=n)
    out = np.full((n, max(int(counts.max()), 1)), n)
    slot = np.arange(pairs.shape[0]) - np.repeat(np.cumsum(counts) - counts, counts)
    out[pairs[:, 0], slot] = pairs[:, 1]
    return out


def _halves(idx: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``idx`` split at the median of its points along their longer side."""
    p = points[idx]
    axis = int(np.argmax(np.ptp(p, axis=0)))
    ranked = idx[np.argsort(p[:, axis], kind="stable")]
    return ranked[:idx.size // 2], ranked[idx.size // 2:]


def _folded(fit: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """An affine fit (1 + d, K) about a box's centre, its points' span ``low``..``high`` (d,) about it:
    the fit's value at the span's centre, then each slope times the span's half-width (1 + d, K), so
    that over the span ``a + b . x`` lies within the first row's value +- the others' sizes."""
    centre, half = (low + high) / 2, (high - low) / 2
    return np.vstack([fit[0] + centre @ fit[1:], half[:, None] * fit[1:]])


def _bounding_rows(shapes: np.ndarray, points: np.ndarray, components: int) -> tuple[np.ndarray, np.ndarray]:
    """A box's rows for its bound (:class:`Cover`'s notes) of every mode (K, m) over ``points`` (m, d):
    the affine fit folded over the span (:func:`_folded`), then the ``components`` leading components of
    its residuals (about their singular value decomposition's, :func:`_leading`; each row ``max_i |u_ij|
    s_j v_j``; rows of zeros where the residuals have fewer), shape (1 + d + components, K), and the
    largest residual they leave on the points (K,)."""
    fit, left, low, high = _affine(shapes, points)
    a, b = _leading(left, components)  # the residuals' leading components: left ~ a @ b.T
    lead = np.abs(a).max(axis=0)[:, None] * b.T
    residual = np.abs(left - a @ b.T).max(axis=0)  # whatever the components, a bound
    rows = np.vstack([_folded(fit, low, high), lead, np.zeros((components - lead.shape[0], shapes.shape[0]))])
    return rows, residual


def _leading(left: np.ndarray, components: int) -> tuple[np.ndarray, np.ndarray]:
    """About the leading ``components`` singular components of ``left`` (m, K), at most its rank:
    ``(a, b)``, (m, j) and (K, j), ``a @ b.T`` close to the rank-j approximation (``U_j s_j`` and ``v_j``),
    by a randomized range finder with one power iteration (Halko, Martinsson and Tropp 2011, 4.4),
    seeded: the same cover every time. Approximate components only loosen a box's bound a little (the
    residual it keeps is computed after them); the tablet's 544 boxes' full SVDs took 1.4 s of its
    plan, this 0.1 s."""
    m, k = left.shape
    kept = min(components, m, k)
    if kept == 0:
        return np.zeros((m, 0)), np.zeros((k, 0))
    probe = np.random.default_rng(0).standard_normal((k, min(kept + OVERSAMPLE, k)))
    range_, _ = np.linalg.qr(left @ probe)
    range_, _ = np.linalg.qr(left @ (left.T @ range_))  # one power iteration: the leading directions sharpened
    u, s, vt = np.linalg.svd(range_.T @ left, full_matrices=False)
    return range_ @ (u[:, :kept] * s[:kept]), vt[:kept].T


def _affine(shapes: np.ndarray, points: np.ndarray):
    """Every mode (K, m) fitted affinely over ``points`` (m, d) about their box's centre: the fit
    (1 + d, K), its residuals on them (m, K), and the points' span about the centre, low and
    high (d,)."""
    centre = 0.5 * (points.max(axis=0) + points.min(axis=0))
    offset = points - centre
    reach = np.where(np.ptp(points, axis=0) > 0, 0.5 * np.ptp(points, axis=0), 1.0)
    design = np.hstack([np.ones((points.shape[0], 1)), offset / reach])  # within [-1, 1]: well conditioned
    fit = np.linalg.lstsq(design.T @ design, design.T @ shapes.T, rcond=None)[0]  # (1 + d, K)
    left = shapes.T - design @ fit  # whatever the fit, its largest is a bound
    fit[1:] /= reach[:, None]
    return fit, left, offset.min(axis=0), offset.max(axis=0)
