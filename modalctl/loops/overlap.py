"""The give-back to modes whose resonances overlap (a drift's, and a touch's): the commands that make its forces,
solved together.

The drift's give-back (:mod:`modalctl.loops.touch`) asks a force ``f_k = -j dw_k y_k / r_k`` of each kept mode
in its own carrier's frame, and each loop's command ``c_k`` is played on mode k's carrier through the plan's
actuator weights ``g_k``. Every mode ``j`` feels every command: ``b_j . g_k c_k`` turning at ``w_k - w_j`` in
its frame. Far from mode j's resonance that turning force passes it by; within its half-power band it drives
the mode as its own command does. On plate-glass's four patches modes 11 and 12 (6651 and 6732 Hz, 80 Hz
apart, half-power half-widths 67 Hz) are pushed along one direction: mode 11's command moves mode 12 2.5 times
as much as mode 11, mode 12's moves mode 11 0.4 times as much, and the two give-backs, each sized for its own
mode, gave both modes twice and more what was asked (the 30 mm bump at (-20, 5) mm, 1% drift: tau 1.050,
margin 0.548; solved together 0.970, 0.527).

:class:`Overlapping` groups the kept modes whose half-power bands overlap, ``|w_i - w_j| < s_i + s_j``
(``s = zeta w``; each with every other of its group), and solves each group's commands from the forces asked:
in mode j's frame at time t the commands give ``F_j = sum_k (b_j . g_k) exp(j (w_k - w_j) t) c_k``, that is
``F = D* C D c`` with ``C`` the group's ``b_j . g_k`` and ``D = diag(exp(j w t))``, so ``c = D* C+ D f``
(``C+``: the pseudo-inverse, directions the patches move ten times less than the group's strongest taken as
none). A pair the patches push along one direction is given the part of the forces they can make, once; a
pair they keep apart (``b_j . g_k = 0``: the dispatch's weights) is given its forces as asked; modes alone
likewise.

A touch's give-back goes through it too in the default controller (``touch+cluster``: the touch controller's
``together``), not over PI loops. A finger near mode 11's antinode drains it (phi 13.6 against mode 12's 1.0),
and mode 11's give-back, sized for it alone, reached mode 12 2.5 times as strongly, 1.2% from its resonance,
where no finger drains it: the margin's excess under a finger on plate-glass (``benchmarks/finger_causes.py``).
Solved together, the resting finger's margin holds on every noise draw there, at a few points of the lost peak
given back; over PI loops, which read the pair's modes each on its own, it was worse: the measurements are in the
touch controller's notes (:class:`~modalctl.loops.touch.TouchControl`).
"""

from __future__ import annotations

import numpy as np

from . import kernels
from .controller import LoopPlant
from .lockin import PeriodTurns

__all__ = ["Overlapping", "overlapping_groups", "RCOND"]

RCOND = 0.1  # directions of a group the patches move less than this share of its strongest: no command


def overlapping_groups(frequencies, damping) -> list[np.ndarray]:
    """The modes (positions, ascending frequency) whose half-power bands overlap, ``2 pi |f_i - f_j| < s_i + s_j``
    with ``s = 2 pi f zeta`` (rad/s), each with every other of its group (a mode joins the group below it
    if it overlaps all of it, else starts the next): groups of two or more. Not chained: on a tablet
    panel's dense upper band (254 modes, 1% damping, eight patches) overlaps chained 94 modes into one group,
    whose eight reachable directions then took most of the give-back (tau 0.974 -> 0.921)."""
    f, zeta = np.asarray(frequencies, float), np.asarray(damping, float)
    sigma = 2 * np.pi * f * zeta
    groups: list[list[int]] = []
    for i in np.argsort(f, kind="stable").tolist():
        group = groups[-1] if groups else []
        if group and all(2 * np.pi * abs(f[i] - f[j]) < sigma[i] + sigma[j] for j in group):
            group.append(i)
        else:
            groups.append([i])
    return [np.array(g) for g in groups if len(g) > 1]


class Overlapping:
    """Called with the forces asked of the kept modes (k,) complex and the control period at whose start they are
    reached (``t = period / control_rate`` gives the carriers' phases), the commands (k,) that make them (the
    module's doc); the forces themselves where the plant has no model (its actuator gains and the plan's
    weights) or no bands overlap. A call costs 5 us on panel-rounded's 9 groups (21 modes).

    Parameters
    ----------
    plant : LoopPlant
        With ``model``, ``modes`` and ``schedule`` (its ``weights`` (a, k) and ``carriers`` (k,) Hz).
    """

    def __init__(self, plant: LoopPlant):
        known = plant.model is not None and plant.modes is not None and plant.schedule is not None
        groups = overlapping_groups(plant.frequencies, plant.damping) if known else []
        self.groups = groups
        if not groups:
            return
        self._index = np.concatenate(groups).astype(np.int64)
        self._zero = np.zeros(plant.frequencies.size, complex)  # no base
        coupling = plant.model.actuator_gains[np.asarray(plant.modes)] @ np.asarray(plant.schedule.weights)  # (k, k)
        inverse = np.zeros((self._index.size, self._index.size), complex)  # block-diagonal: one product a call
        start = 0
        for g in groups:
            inverse[start:start + g.size, start:start + g.size] = np.linalg.pinv(coupling[np.ix_(g, g)], rcond=RCOND)
            start += g.size
        self._inverse = inverse
        self._turn = PeriodTurns(2 * np.pi * np.asarray(plant.schedule.carriers, float)[self._index]
                                 / plant.control_rate)  # D's diagonal at a period's start

    def __call__(self, forces: np.ndarray, period: int, base: np.ndarray | None = None) -> np.ndarray:
        """The commands (k,) that make ``forces``, plus ``base`` (k,) when given (commands made otherwise)."""
        if not self.groups:
            return forces if base is None else base + forces
        commands = np.empty(forces.size, complex)
        kernels.overlap_commands(np.asarray(forces, complex), self._zero if base is None else base, self._index,
                                 self._turn(period), self._inverse, commands)
        return commands  # D^* inverse D on the overlapping modes, the forces elsewhere
