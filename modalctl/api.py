"""The front door: a researcher's path from a scene to a shot, and every contract a plugin implements.

One import serves both::

    from modalctl import api as mc

    model = mc.load_scene("thesis-al-cc")
    sinc = mc.make_shape("sinc", model, width="18mm", center="24mm")
    with mc.connect("sim://", model=model, target=sinc, drift=0.01, snr=40) as device:
        shot = mc.run(model, sinc, device, mc.RunOptions(25e-3, loop=mc.LoopOptions()))
    print(shot.metrics.tau, shot.loop.crossover_hz)

Options take a plugin's name or the plugin object itself: ``mc.PlanOptions(planner=MyPlanner())``,
``mc.LoopOptions(controller=MyController())``; names are resolved once, by :func:`run`, through the
plugin manager (installed plugins, registered under the ``modalctl`` entry point group with
:func:`hookimpl`).

The contracts are abstract base classes with defaults; a plugin subclasses one and fills what it
marks abstract:

- :class:`ShapeGenerator` (hook ``modalctl_shapes``): ``generate(grid, **params) -> Shape``;
- :class:`Planner` (``modalctl_planners``): ``plan(dec, focus_time, options, progress) -> Plan``,
  with a :class:`PlanReport` whose fields all have defaults;
- :class:`ControllerFactory` (``modalctl_controllers``): ``create(plant) -> Controller``, a
  :class:`Controller` having ``reset()`` and ``update(error, limit)``;
- :class:`Identifier` (``modalctl_identifiers``): ``identify(frf, threshold_db) -> Modes``;
- :class:`TrackerFactory` (``modalctl_trackers``): ``create(frequencies, damping, control_rate)``;
- :class:`Device` (``modalctl_transports``): ``configure``, ``upload``, ``trigger``...

``docs/plugins.md`` shows a complete planner and controller written against this module.
"""

from __future__ import annotations

from modalctl.errors import InputError
from modalctl.identify.estimators import Identifier, Modes
from modalctl.identify.frf import FRF
from modalctl.identify.trackers import TrackerFactory
from modalctl.io.device import Capabilities, Capture, Device, DeviceContext, DeviceError, open_device
from modalctl.loops.controller import Controller, ControllerFactory, LoopDesign, LoopPlant
from modalctl.model.modes import Grid, ModalModel, ModelError
from modalctl.model.scenes import SCENES, load_scene
from modalctl.model.shape import Param, ParamError, Shape, ShapeGenerator, generated, parse_params
from modalctl.options import ConvexOptions, LoopOptions, PlanOptions, RunOptions, SurveyOptions
from modalctl.plan.decompose import Decomposition, decompose
from modalctl.plan.dispatch import dispatch
from modalctl.plan.drive import Drive, EnvelopeDrive, SplineDrive
from modalctl.plan.growth import Growth, model_for
from modalctl.plan.planner import Plan, PlanError, Planner, PlanReport, controllable, plan, plan_shot
from modalctl.plugin.manager import PluginError, pick, plugin_manager
from modalctl.plugin.spec import hookimpl
from modalctl.run import ShotResult, run

__all__ = [
    # the researcher's path
    "load_scene", "load_model", "SCENES", "make_shape", "model_for", "Growth", "decompose", "plan", "plan_shot",
    "connect", "run",
    "RunOptions", "PlanOptions", "LoopOptions", "ConvexOptions", "SurveyOptions",
    "ModalModel", "Grid", "Shape", "Decomposition", "Plan", "PlanReport", "ShotResult",
    # the contracts and the hook marker
    "hookimpl", "ShapeGenerator", "Param", "Planner", "Drive", "EnvelopeDrive", "SplineDrive", "dispatch",
    "controllable", "ControllerFactory",
    "Controller", "LoopPlant", "LoopDesign", "Identifier", "Modes", "FRF", "TrackerFactory", "Device",
    "DeviceContext", "Capabilities", "Capture",
    # errors
    "InputError", "ModelError", "ParamError", "PlanError", "DeviceError", "PluginError",
    "plugin_manager",
]


def load_model(path) -> ModalModel:
    """A modal model from its ``.npz`` file (written by ``modalctl model fe``, ``identify`` or
    :meth:`ModalModel.save`)."""
    return ModalModel.load(path)


def make_shape(generator: str | ShapeGenerator, model: ModalModel, manager=None, **params) -> Shape:
    """The target field of ``generator`` (a name or a :class:`ShapeGenerator`) on ``model``'s grid.

    ``params`` are the generator's parameters, as text with units (``width="18mm"``) or numbers in
    SI units (``width=0.018``); defaults filled in, bad ones refused with :class:`ParamError`.
    """
    return generated(pick("shape", generator, manager), model.grid, params)


def connect(url: str = "sim://", *, model: ModalModel | None = None, target: Shape | None = None, manager=None,
            **options) -> Device:
    """Open the device at ``url`` (``sim://``, ``serial:///dev/ttyUSB0``, ``can://socketcan/can0``...).

    ``model`` and ``target`` are what the shot is planned on (the simulator simulates ``model``);
    ``options`` are the transport's own options by name, in SI units, as its command-line options
    (``sim://``: ``drift=0.01``, ``snr=40``, ``finger=1.0``...; ``modalctl run --help`` lists them).
    """
    return open_device(url, DeviceContext(model, target, options), manager)
