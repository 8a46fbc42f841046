"""Scenario sweeps on the HIL: one focus case per point, several ways of driving it.

A :class:`Case` is one point of a sweep: the scene and shape, the truth's departure from the
model (drift, damping error, a finger, loop latency, sensor noise) and the method:

- ``open``: the plan's feed-forward alone (the thesis);
- ``closed``: feed-forward plus the per-mode loops;
- ``tracked``: a first closed-loop shot during which the pole tracker learns each mode, then the
  plan remade on the tracked model and played closed loop (the number reported is the second shot's);
- ``learned``: a first closed-loop shot whose record updates the model's resonances and damping
  (:func:`modalctl.identify.updating.update`), then the plan remade on it and played closed loop.

Every case is :func:`modalctl.run.run` on a ``sim://`` device, the path ``modalctl run`` takes: the
field is measured by the simulated vibrometer, with its noise. :func:`run_case` is a plain function
of a picklable case, so any executor (:mod:`modalctl.experiments.executor`) can run a sweep's cases
wherever it runs things.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import asdict, dataclass
from functools import lru_cache

import numpy as np

from modalctl.errors import InputError
from modalctl.io.device import DeviceContext, open_device
from modalctl.model.scenes import load_scene
from modalctl.model.shape import generated
from modalctl.model.touch import Touch, added_decay
from modalctl.options import THESIS_PLAN, LoopOptions, PlanOptions, RunOptions
from modalctl.plan.growth import model_for
from modalctl.plan.planner import PlanError, plan_shot
from modalctl.plugin.manager import get_shape
from modalctl.run import LearningStopped, run

__all__ = ["Case", "run_case", "METHODS"]

METHODS = ("open", "closed", "tracked", "learned")
LEARNING = {"open": None, "closed": None, "tracked": "tracker", "learned": "record"}


@dataclass(frozen=True)
class Case:
    """One point of a sweep.

    Attributes
    ----------
    scene, shape : str
    params : tuple of (name, value) pairs
        Shape parameters with units, e.g. ``(("width", "18mm"), ("center", "24mm"))``.
    focus_time : float
        s.
    method : {"open", "closed", "tracked", "learned"}
    drift, damping_error : float
        Relative shift of every resonance and relative damping error of the truth.
    finger : float
        Viscous damping of a finger at the shape's centre (N s/m); 0 for none.
    latency : int
        Extra control periods the board takes to use a command.
    snr_db : float or None
    planner : str
        Planner plugin (the thesis's envelopes by default: the sweeps measure the feedback on the
        plan the thesis played).
    margin : float or None
        Transient margin the plan is optimized for.
    modes : int or None
        Keep the N lowest modes (the thesis's counts); None chooses them automatically.
    points : int or None
        Grid points of a beam scene.
    control_rate, sample_rate : float
        Hz.
    controller : str or None
        Controller plugin of the closed loops (None: :attr:`LoopOptions.chosen_controller`).
    authority : float
        Largest feedback command of a mode, as a fraction of its planned drive at that moment.
    seed : int
    voltage_limit : float or None
        Largest drive voltage the plan may use (V; ``modalctl sweep`` gives the model's actuators' safe
        voltage unless told otherwise, as ``run`` does).
    tau_target : float or None
        Least tau of the automatic mode set, and of a finite-element plate's grown model (None: the
        plan's default, :attr:`~modalctl.options.PlanOptions.tau_min`).
    """

    scene: str = "thesis-al-cc"
    shape: str = "sinc"
    params: tuple = (("width", "18mm"), ("center", "24mm"))
    focus_time: float = 25e-3
    method: str = "closed"
    drift: float = 0.0
    damping_error: float = 0.0
    finger: float = 0.0
    latency: int = 0
    snr_db: float | None = 40.0
    planner: str = THESIS_PLAN.planner
    margin: float | None = THESIS_PLAN.margin
    modes: int | None = None
    points: int | None = 211
    control_rate: float = 20e3
    sample_rate: float = 500e3
    controller: str | None = LoopOptions.controller
    authority: float = LoopOptions.authority
    seed: int = 0
    voltage_limit: float | None = None
    tau_target: float | None = None

    def __post_init__(self):
        if self.method not in METHODS:
            raise InputError(f"method must be one of {METHODS}, got {self.method!r}")

    def options(self) -> RunOptions:
        """The shot's options: the plan's, and the loops' unless open loop."""
        plan = THESIS_PLAN.but(planner=self.planner, modes=self.modes or "auto", margin=self.margin,
                               sample_rate=self.sample_rate, voltage_limit=self.voltage_limit,
                               tau_min=self.tau_target or THESIS_PLAN.tau_min)
        loop = None if self.method == "open" else LoopOptions(
            control_rate=self.control_rate, controller=self.controller, authority=self.authority, latency=self.latency)
        return RunOptions(self.focus_time, plan, loop, LEARNING[self.method])


@lru_cache(maxsize=8)
def _model_shape(scene: str, points, shape: str, params: tuple, planned: PlanOptions):
    """The scene's model and the target on it; a finite-element plate's model grown until its modes
    draw the shape, as ``modalctl run`` grows it (:func:`~modalctl.plan.growth.model_for`), so that a
    sweep plays the shots ``run`` would (panel-rounded's 30 mm bump: 22 modes reach tau 0.957, refused
    at the default target, where ``run`` grows it to 53)."""
    model = load_scene(scene, points)
    target = generated(get_shape(shape), model.grid, dict(params))
    return model_for(model, target, planned)[0], target


@lru_cache(maxsize=8)
def _nominal_plan(scene: str, points, shape: str, params: tuple, focus_time: float, planned: PlanOptions):
    """The plan on the model, made once for every truth and every method a sweep plans alike
    (``planned``: :attr:`modalctl.options.RunOptions.planned`, a closed loop's with its headroom)."""
    model, target = _model_shape(scene, points, shape, params, planned)
    return plan_shot(model, target, focus_time, planned)


def run_case(case: Case) -> dict:
    """Play one case on the HIL; returns the case's fields plus ``tau``, ``margin_ratio``,
    ``peak_voltage``, ``state`` (how the runtime ended), ``fault``, ``seconds`` and, after a
    learning shot, ``first_shot_tau``. A case the shot refuses (its loops cannot be designed, its
    plan after a learning shot cannot be made: :class:`InputError`, :class:`PlanError`) is a row
    too: ``state`` ``"refused"``, the reason in ``fault``, no metrics; the sweep goes on (one case of
    panel-rounded's 48, learned at 3% drift, ended a whole closed_maps run)."""
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        options = case.options()
        model, target = _model_shape(case.scene, case.points, case.shape, case.params, options.planned)
        planned = _nominal_plan(case.scene, case.points, case.shape, case.params, case.focus_time, options.planned)
        peak = int(np.argmax(np.abs(target.values)))  # where the simulator rests the finger
        truth = {"drift": case.drift, "damping_error": case.damping_error, "snr": case.snr_db, "seed": case.seed,
                 "finger": case.finger}
        device = open_device("sim://", DeviceContext(model, target, truth))
        try:
            shot = run(model, target, device, options, planned)
        except LearningStopped as stopped:  # a result of the case: the first shot's, as measured to the stop
            shot = stopped.shot
        except (InputError, PlanError) as refused:
            return {**asdict(case), "params": dict(case.params), "tau": None, "margin_ratio": None,
                    "peak_voltage": None, "state": "refused", "fault": str(refused),
                    "finger_added_damping_max": None, "seconds": time.perf_counter() - start}
    added = 0.0
    if case.finger > 0:
        modes = planned[1].modes
        added = added_decay(device.truth, Touch(peak, case.finger))[modes] / (device.truth.damping * device.truth.omega)[modes]
        added = float(np.max(added))
    row = {**asdict(case), "params": dict(case.params), "tau": shot.metrics.tau,
           "margin_ratio": shot.metrics.margin_ratio, "peak_voltage": shot.metrics.peak_voltage,
           "state": "inactive" if shot.loop is None else shot.loop.state, "fault": shot.fault,
           "finger_added_damping_max": added, "seconds": time.perf_counter() - start}
    if shot.learning is not None:
        row["first_shot_tau"] = shot.learning.tau
    return row
