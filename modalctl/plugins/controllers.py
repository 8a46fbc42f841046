"""First-party per-mode controllers: PI loops designed on margins, a Kalman observer with LQ feedback,
PI loops that give back the force a touch takes, LQG loops that control close modes together, and
the default: the touch's give-back over the close modes' laws and PI loops on the others.

Each is a :class:`~modalctl.loops.controller.ControllerFactory` subclass, as a third party's would
be. They are designed with python-control, which loads matplotlib's pyplot when imported: the
modules that design are imported when a controller is made, so that listing plugins or planning a
shot does not pay for it.
"""

from __future__ import annotations

from modalctl.loops.controller import Controller, ControllerFactory, LoopPlant
from modalctl.plugin.spec import hookimpl


class PI(ControllerFactory):
    name = "pi"
    summary = "PI per mode, zero on the mode's pole, the highest crossover that keeps 50 deg and 6 dB with the " \
              "lock-in and the latency (default)"

    def create(self, plant: LoopPlant, **options) -> Controller:
        from modalctl.loops.design import pi_controller

        return pi_controller(plant, **options)


class LQG(ControllerFactory):
    name = "lqg"
    summary = "per-mode Kalman observer of the envelope model (detuning, latency, lock-in) with LQ state " \
              "feedback and integral action"

    def create(self, plant: LoopPlant, **options) -> Controller:
        from modalctl.loops.lqg import LQGControl

        return LQGControl(plant, **options)


class Touch(ControllerFactory):
    name = "touch"
    summary = "PI per mode plus the force a touch takes: its damping and place estimated from every mode's " \
              "envelope during the shot, given back on the planned motion"
    senses_touch = True

    def create(self, plant: LoopPlant, inner: ControllerFactory | None = None, **options) -> Controller:
        """``inner``: the loops the touch's force is added to (the PI's by default)."""
        from modalctl.loops.touch import TouchControl

        return TouchControl(plant, (inner or PI()).create(plant), **options)


class TouchCluster(ControllerFactory):
    name = "touch+cluster"
    summary = "the touch controller over one LQ law per cluster of close modes, PI on the modes in no cluster " \
              "(default)"
    senses_touch = True

    def create(self, plant: LoopPlant, **options) -> Controller:
        from modalctl.loops.cluster import ClusterControl
        from modalctl.loops.touch import TouchControl

        return TouchControl(plant, ClusterControl(plant, alone="pi"), **{"together": True, **options})


class Cluster(ControllerFactory):
    name = "cluster"
    summary = "per-mode LQG, but one multivariable Kalman observer and LQ law with integral action for each " \
              "cluster of modes whose lock-in bands overlap (the coupled envelope model in a common frame)"

    def create(self, plant: LoopPlant, **options) -> Controller:
        from modalctl.loops.cluster import ClusterControl

        return ClusterControl(plant, **options)


@hookimpl
def modalctl_controllers():
    return [PI(), LQG(), Touch(), TouchCluster(), Cluster()]
