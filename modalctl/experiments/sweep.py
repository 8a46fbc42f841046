"""Scenario sweeps on the HIL: one focus case per point, three ways of driving it.

A :class:`Case` is one point of a sweep: the scene and shape, the truth's departure from the
model (drift, damping error, a finger, loop latency, sensor noise) and the method:

- ``open``: the plan's feed-forward alone (the thesis);
- ``closed``: feed-forward plus the per-mode loops;
- ``tracked``: a first closed-loop shot during which the pole tracker learns each mode, then the
  plan remade on the tracked model and played closed loop (the number reported is the second shot's);
- ``learned``: a first closed-loop shot whose record updates the model's resonances and damping
  (:func:`modalctl.identify.updating.update`), then the plan remade on it and played closed loop.

:func:`run_case` is a plain function of a picklable case, so any executor
(:mod:`modalctl.experiments.executor`) can run a sweep's cases wherever it runs things.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import asdict, dataclass, replace
from functools import lru_cache

import numpy as np

from modalctl.hil.finger import Finger, FingerPlant, added_damping
from modalctl.hil.scenario import Perturbation, perturb
from modalctl.identify.trackers import updated_model
from modalctl.identify.updating import update
from modalctl.loops.schedule import HOLD
from modalctl.loops.shot import AUTHORITY
from modalctl.model.scenes import load_scene
from modalctl.model.shape import parse_params
from modalctl.plan.decompose import decompose
from modalctl.plan.planner import plan
from modalctl.plugin.manager import get_shape, get_tracker

from .focus import run_focus

__all__ = ["Case", "run_case", "METHODS"]

METHODS = ("open", "closed", "tracked", "learned")
LEARNING_SEED = 10007  # offset of a learning shot's noise seed


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
    margin : float or None
        Transient margin the plan is optimized for.
    modes : int or None
        Keep the N lowest modes (the thesis's counts); None chooses them automatically.
    points : int or None
        Grid points of a beam scene.
    control_rate, sample_rate : float
        Hz.
    controller : str
        Controller plugin of the closed loops.
    authority : float
        Largest feedback command of a mode, as a fraction of its planned drive at that moment.
    seed : int
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
    margin: float | None = None
    modes: int | None = None
    points: int | None = 211
    control_rate: float = 20e3
    sample_rate: float = 500e3
    controller: str = "pi"
    authority: float = AUTHORITY
    seed: int = 0

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {self.method!r}")


@lru_cache(maxsize=8)
def _model_shape(scene: str, points, shape: str, params: tuple):
    model = load_scene(scene, points)
    generator = get_shape(shape)
    return model, generator.generate(model.grid, **parse_params(generator, dict(params)))


def _plan(model, target, case: Case):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # a margin is held on the whole model, as modalctl run does by default
        return plan(decompose(model, target, case.modes or "auto"), case.focus_time, margin=case.margin,
                    sample_rate=case.sample_rate, verify="planned" if case.margin is None else "whole")


@lru_cache(maxsize=8)
def _nominal_plan(case: Case):
    model, target = _model_shape(case.scene, case.points, case.shape, case.params)
    return _plan(model, target, case)


def run_case(case: Case) -> dict:
    """Play one case on the HIL; returns the case's fields plus ``tau``, ``margin_ratio``,
    ``peak_voltage``, ``state`` (how the runtime ended), ``fault`` and ``seconds``."""
    start = time.perf_counter()
    model, target = _model_shape(case.scene, case.points, case.shape, case.params)
    shot = _nominal_plan(replace(case, method="open", drift=0.0, damping_error=0.0, finger=0.0, latency=0, seed=0))
    truth = perturb(model, Perturbation(drift=case.drift, damping_error=case.damping_error))
    added = 0.0
    if case.finger > 0:
        finger = Finger(int(np.argmax(np.abs(target.values))), case.finger)
        added = float(np.max(added_damping(truth, finger)[shot.modes] / truth.damping[shot.modes]))
        truth = FingerPlant(truth, finger, case.sample_rate)
    options = dict(control_rate=case.control_rate, snr_db=case.snr_db, latency=case.latency, seed=case.seed,
                   controller=case.controller, authority=case.authority)
    first = None
    learning = {**options, "seed": case.seed + LEARNING_SEED}  # the first shot's noise is not the second's
    if case.method == "tracked":
        modes = shot.modes
        tracker = get_tracker("pole").create(model.frequencies[modes], model.damping[modes], case.control_rate,
                                             retune=np.inf)  # the carriers stay on the plan's during a shot
        first = run_focus(truth, shot, target, tracker=tracker, **learning)
        shot = _plan(updated_model(model, modes, tracker), target, case)
    elif case.method == "learned":
        first = run_focus(truth, shot, target, **learning)
        board = first.board
        shot = _plan(update(model, board.applied, board.sensed, case.sample_rate, hold=HOLD).model, target, case)
    result = run_focus(truth, shot, target, closed=case.method != "open", **options)
    row = {**asdict(case), "params": dict(case.params), "tau": result.tau, "margin_ratio": result.margin_ratio,
           "peak_voltage": result.peak_voltage, "state": result.result.state.name.lower(),
           "fault": result.result.reason, "finger_added_damping_max": added,
           "seconds": time.perf_counter() - start}
    if first is not None:
        row["first_shot_tau"] = first.tau
    return row
