"""Hardware-in-the-loop: emulated hardware and nothing else.

The truth and its mode cut-off (:mod:`.plant`), what makes it differ from the model
(:mod:`.scenario`: drift, damping error, noise, amplifier), a finger on the surface
(:mod:`.finger`), the ``sim://`` device (:mod:`.sim_device`), the board in phasor mode
(:mod:`.phasor_board`, played a control period at a time by :mod:`.block` and :mod:`.lifted`), and the
board side of the protocol (:mod:`.emulator`) on a pty (:mod:`.serial_board`) or a CAN FD bus
(:mod:`.can_board`). Experiments that use it live in :mod:`modalctl.experiments`.
"""
