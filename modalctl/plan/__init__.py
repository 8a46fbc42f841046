"""The high level: from a target field to each kept mode's reference and the voltages that make it.

Decomposition on the modes and reduction to the modes a scene needs (:mod:`.decompose`,
:mod:`.reduction`), per-mode references and their exact drive (:mod:`.reference`), sharing each
mode's drive among the actuators (:mod:`.dispatch`), and the planner (:mod:`.planner`) with its
envelope optimizer (:mod:`.envelopes`) and the whole-model voltage correction (:mod:`.refine`).

Imports :mod:`modalctl.model` and the plugin manager; nothing above.
"""
