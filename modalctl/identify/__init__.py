"""Where models come from when they are measured: FRFs, modal parameter estimators, surveys, updating, trackers.

Excitation and FRFs (:mod:`.frf`), acquisition through any device (:mod:`.acquire`), the
estimators (:mod:`.estimators`: peak picking, SDOF fit) and a whole survey of a device
(:mod:`.survey`); a model updated from one shot's record (:mod:`.updating`) and the online
resonance trackers (:mod:`.trackers`).

Imports the layers below (model, plan, loops, io) and the plugin manager.
"""
