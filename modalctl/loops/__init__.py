"""The low level: per-mode loops that track the planner's references during a shot.

From the plan to each control period's references (:mod:`.schedule`) through lock-ins
(:mod:`.lockin`) and the sensors' combinations (:mod:`.sensing`); the controller contract
(:mod:`.controller`), the PI law (:mod:`.pi`) and its design with python-control
(:mod:`.design`), a Kalman/LQ alternative (:mod:`.lqg`); the supervisor that owns safety
(:mod:`.supervisor`); the runtime's lifecycle and read/update/write loop and the board contract
it drives (:mod:`.runtime`); a closed-loop shot assembled from a plan (:mod:`.shot`), its log
(:mod:`.recorder`), the loops loaded into a board (:mod:`.onboard`), and the process set-up for
real-time loops (:mod:`.realtime`).

Imports :mod:`modalctl.model`, :mod:`modalctl.plan` and the plugin manager; it opens no port and
knows boards only through :class:`~modalctl.loops.runtime.PhasorBoard`.
"""
