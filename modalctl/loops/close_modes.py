"""Which kept modes' loops read each other: the clusters of close modes the ``cluster`` controller
(:mod:`modalctl.loops.cluster`) controls as one, the rule that links them (:func:`find_clusters`) and
what a run reports of them whatever its controller (:func:`clusters_of`)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

__all__ = ["Clusters", "find_clusters", "clusters_of", "BAND_RULE", "MARGIN_RULE"]


@dataclass(frozen=True)
class Clusters:
    """Which kept modes are controlled together, and why.

    Attributes
    ----------
    groups : tuple of tuple of int
        Positions (in the kept modes) of each cluster's modes, two or more each, ascending.
    pairs : tuple of (int, int, float, float)
        ``(i, j, spacing, threshold)`` for every pair linked (``spacing < threshold``) and every pair
        of kept modes adjacent in frequency: carrier spacing and the rule's threshold (Hz).
    frequencies : tuple of float
        The kept modes' carriers (Hz; empty if not given): the order :meth:`summary` reads a cluster in.
    rule : str
        The rule that linked them, in words (:data:`BAND_RULE` or :data:`MARGIN_RULE`).
    refused : tuple of (tuple of int, str)
        Groups the rule linked that keep per-mode loops, and why (their law has no solution, or is not
        stable over the drift band: :class:`~modalctl.loops.cluster.ClusterControl`).
    """

    groups: tuple
    pairs: tuple
    frequencies: tuple = ()
    rule: str = ""
    refused: tuple = ()

    def lines(self, labels=None) -> list[str]:
        """One line per pair: what the planner or the report prints (``labels``: the kept modes' names)."""
        name = (lambda i: str(i)) if labels is None else (lambda i: str(labels[i]))
        return [f"modes {name(i)} and {name(j)}: {spacing:.1f} Hz apart, "
                f"{'below' if spacing < threshold else 'above'} {threshold:.1f} Hz: "
                f"{'one cluster' if spacing < threshold else 'apart'}" for i, j, spacing, threshold in self.pairs]

    def to_dict(self, labels=None) -> dict:
        """JSON-ready (the run's ``metrics.json``): ``groups`` as lists of the kept modes' names (their
        positions without ``labels``), ``pairs`` with ``modes``, ``spacing_hz``, ``threshold_hz`` and ``linked``."""
        name = (lambda i: int(i)) if labels is None else (lambda i: labels[i])
        return {"rule": self.rule, "groups": [[name(i) for i in g] for g in self.groups],
                "pairs": [{"modes": [name(i), name(j)], "spacing_hz": spacing, "threshold_hz": threshold,
                           "linked": bool(spacing < threshold)} for i, j, spacing, threshold in self.pairs],
                "refused": [{"modes": [name(i) for i in g], "why": why} for g, why in self.refused]}

    def summary(self, labels=None) -> list[str]:
        """One line per cluster: its modes and, for each two adjacent in frequency, their carrier spacing
        against the rule's threshold (Hz); with no cluster, one line naming the closest pair and its margin."""
        name = (lambda i: str(i)) if labels is None else (lambda i: str(labels[i]))
        refused = [f"modes {', '.join(name(i) for i in group)}: per-mode loops, {why}" for group, why in self.refused]
        if not self.groups and refused:
            return refused
        if not self.groups:
            if not self.pairs:
                return ["no cluster: a single kept mode"]
            i, j, spacing, threshold = min(self.pairs, key=lambda p: p[2] / p[3])
            return [f"no cluster: the nearest to one, modes {name(i)} and {name(j)}, {spacing:.1f} Hz apart, "
                    f"above {threshold:.1f} Hz"]
        known = {(i, j): (spacing, threshold) for i, j, spacing, threshold in self.pairs}
        out = []
        for group in self.groups:
            group = sorted(group, key=lambda i: self.frequencies[i]) if self.frequencies else list(group)
            links = [(i, j, known.get((min(i, j), max(i, j)))) for i, j in zip(group[:-1], group[1:])]
            out.append(f"modes {', '.join(name(i) for i in group)}: " + "; ".join(
                f"{name(i)}-{name(j)} {pair[0]:.1f} Hz apart, {'below' if pair[0] < pair[1] else 'above'} {pair[1]:.1f}"
                for i, j, pair in links if pair is not None))
        return out + refused


BAND_RULE = "|f_i - f_j| < max(B_i + fc_j, B_j + fc_i) (B: lock-in corner, fc: crossover)"
MARGIN_RULE = "|f_i - f_j| < max(fc_i, fc_j) + the spacing where the lock-ins' attenuations |H_i| |H_j| fall to " \
              "1 - 10^(-GM/20), GM the pair's smaller gain margin (fc: crossover)"


def find_clusters(frequencies, bandwidths, crossovers, margins_db=None) -> Clusters:
    """The kept modes whose loops read each other.

    Loop j's feedback moves its envelope within its crossover ``fc_j``; in loop i's frame that motion
    sits at the carriers' difference ``|f_i - f_j|``, spread over ``+- fc_j``, and loop i's lock-in
    passes what lies below its corner ``B_i``. So modes i and j are linked when
    ``|f_i - f_j| < max(B_i + fc_j, B_j + fc_i)`` and a cluster is a connected group of links.

    With the loops' gain margins, a pair is linked only where the path around both loops could take a loop
    to its stability limit: each lock-in (:func:`~modalctl.loops.design.lockin_filter`, a Butterworth of
    order ``LOCKIN_ORDER``) attenuates the other's carrier by ``|H_i(f_i - f_j)|``; at its phase crossover a
    loop's gain is ``10^(-GM / 20)``, ``1 - 10^(-GM / 20)`` from -1, and the pair is linked when
    ``|H_i| |H_j| > 1 - 10^(-min(GM_i, GM_j) / 20)`` a crossover nearer: the threshold (Hz) is the spacing
    where the product meets that distance, plus ``max(fc_i, fc_j)``. The paths' own gains (how much each
    loop's sensors read the other's mode) are taken as one: an upper bound for clean readings.

    Parameters
    ----------
    frequencies, bandwidths, crossovers : array_like, shape (k,)
        Carriers, lock-in corners and the loops' crossovers (Hz), e.g. the PI design's
        (:func:`~modalctl.loops.design.design_loops`), which the LQ loops aim at.
    margins_db : array_like, shape (k,), optional
        The loops' gain margins (dB): the attenuation rule above instead of the corners'.
    """
    f, b, fc = (np.asarray(x, float) for x in (frequencies, bandwidths, crossovers))
    limit = None if margins_db is None else _attenuation_spacing(b, np.asarray(margins_db, float))
    order = np.argsort(f)
    adjacent = {tuple(sorted(map(int, pair))) for pair in zip(order[:-1], order[1:])}
    parent = list(range(f.size))

    def root(i: int) -> int:
        while parent[i] != i:
            i = parent[i]
        return i

    pairs = []
    for i in range(f.size):
        for j in range(i + 1, f.size):
            spacing = abs(f[i] - f[j])
            threshold = max(b[i] + fc[j], b[j] + fc[i]) if limit is None else limit[i, j] + max(fc[i], fc[j])
            if spacing < threshold:
                parent[root(j)] = root(i)
            if spacing < threshold or (i, j) in adjacent:
                pairs.append((i, j, float(spacing), float(threshold)))
    groups: dict = {}
    for i in range(f.size):
        groups.setdefault(root(i), []).append(i)
    return Clusters(tuple(tuple(g) for g in groups.values() if len(g) > 1), tuple(pairs), tuple(f.tolist()),
                    BAND_RULE if limit is None else MARGIN_RULE)


LOCKIN_ORDER = 4  # lockin_filter's


def _attenuation_spacing(bandwidths: np.ndarray, margins_db: np.ndarray) -> np.ndarray:
    """The spacing (Hz) at which two lock-ins' attenuations multiply to ``m = 1 - 10^(-GM / 20)`` (the pair's
    smaller gain margin GM, dB), (k, k).

    ``|H(x)|^2 = 1 / (1 + (x / B)^(2n))`` for a Butterworth of order n, so with ``y = x^(2n)``,
    ``p = B_i^(-2n)``, ``q = B_j^(-2n)`` and ``c = 1 / m^2 - 1``: ``p q y^2 + (p + q) y - c = 0``."""
    n2 = 2 * LOCKIN_ORDER
    scale = np.max(bandwidths)
    p = (scale / bandwidths) ** n2  # in units of the largest corner: no overflow
    pq, total = p[:, None] * p[None, :], p[:, None] + p[None, :]
    gm = np.minimum(margins_db[:, None], margins_db[None, :])
    c = 1 / (1 - 10 ** (-np.where(np.isfinite(gm), gm, 200.0) / 20)) ** 2 - 1
    y = 2 * c / (total + np.sqrt(total ** 2 + 4 * pq * c))
    return scale * y ** (1 / n2)


def clusters_of(controller, frequencies, bandwidths) -> tuple[Clusters, bool]:
    """The clusters a run reports, whatever its controller: ``(clusters, together)``. A controller that
    controls clusters together (its own ``clusters``, or an inner controller's: the touch controller's)
    gives its own and ``together`` True; for per-mode loops, :func:`find_clusters` on their design's
    crossovers and gain margins says which of them read each other (``together`` False).

    Parameters
    ----------
    controller : Controller
    frequencies, bandwidths : array_like, shape (k,)
        The kept modes' carriers and lock-in corners (Hz).
    """
    inner = controller
    while inner is not None:
        if isinstance(getattr(inner, "clusters", None), Clusters):
            found = inner.clusters
            return (found if found.frequencies else replace(found, frequencies=tuple(map(float, frequencies)))), True
        inner = getattr(inner, "inner", None)
    design = controller.design
    return find_clusters(frequencies, bandwidths, design.crossover_hz, design.gain_margin_db), False
