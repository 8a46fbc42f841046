"""The lowest layer: what a structure is and how it moves.

Grids with mass weights and modal models (:mod:`.modes`, :mod:`.files`), analytic structures
(:mod:`.structures`) and the named scenes built from them (:mod:`.scenes`), target fields and
their typed parameters (:mod:`.shape`), the mass-weighted projection (:mod:`.projection`),
accuracy metrics (:mod:`.metrics`) and the exact sampled propagation of the modes
(:mod:`.propagate`, shared by the planner's predictions and the simulator's truth).

Imports nothing of modalctl but :mod:`modalctl.units` and :mod:`modalctl.options`.
"""
