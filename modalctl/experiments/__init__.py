"""Scenario drivers on the hardware-in-the-loop simulator: focus shots on a given truth, tracking runs,
sweeps over scenarios (:mod:`.sweep`) and where their cases run (:mod:`.executor`).

The top of the house under the command line: it may import every layer, and the simulator.
"""
