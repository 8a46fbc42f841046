"""Hook specifications of ``modalctl`` plugins (pluggy project name and entry point group ``modalctl``).

A plugin is a module or object with functions marked ``@hookimpl`` whose names match the
specs below. Register it under the ``modalctl`` entry point group in its ``pyproject.toml``::

    [project.entry-points.modalctl]
    myshapes = "mypackage.shapes"

Every hook here is documented in ``docs/plugins.md`` (a test fails otherwise).
"""

from __future__ import annotations

from typing import Any, Callable, TypeVar, cast

import pluggy

__all__ = ["hookspec", "hookimpl", "modalctl_shapes", "modalctl_planners", "modalctl_transports",
           "modalctl_add_options", "modalctl_identifiers", "modalctl_trackers", "modalctl_controllers",
           "modalctl_commands"]

_F = TypeVar("_F", bound=Callable[..., Any])
_spec = pluggy.HookspecMarker("modalctl")
_impl = pluggy.HookimplMarker("modalctl")


def hookspec(function: _F) -> _F:
    """Mark ``function`` as a hook specification (typed wrapper of pluggy's marker)."""
    return cast(_F, _spec(function))


def hookimpl(function: _F) -> _F:
    """Mark ``function`` as a hook implementation; keeps its signature for type checkers."""
    return cast(_F, _impl(function))


@hookspec
def modalctl_shapes():
    """Return the shape generators this plugin provides.

    Returns
    -------
    iterable of modalctl.model.shape.ShapeGenerator
        Objects with ``name``, ``summary``, ``params`` and ``generate(grid, **params)``.
        Names must be unique across installed plugins.
    """


@hookspec
def modalctl_planners():
    """Return the planners this plugin provides (the hierarchy's high level).

    Returns
    -------
    iterable of modalctl.plan.planner.Planner
        Objects with ``name``, ``summary`` and ``plan(dec, focus_time, options, progress)``
        returning a :class:`modalctl.plan.planner.Plan` (or raising
        :class:`modalctl.plan.planner.PlanError`); ``options`` is a
        :class:`modalctl.options.PlanOptions`. Names must be unique across installed plugins.
    """


@hookspec
def modalctl_transports():
    """Return the transports this plugin provides, by URL scheme.

    Returns
    -------
    dict of str to callable
        ``{scheme: factory}``; ``factory(url, context)`` returns a :class:`modalctl.io.device.Device`.
        ``context`` is a :class:`modalctl.io.device.DeviceContext`: the model the shot is planned
        on, its target, and the transport's own command-line options (see
        :func:`modalctl_add_options`), parsed.
    """


@hookspec
def modalctl_add_options(options):
    """Add this plugin's transports' command-line options (as pytest's ``pytest_addoption``).

    Parameters
    ----------
    options : modalctl.io.device.TransportOptions
        ``options.group(scheme, title)`` is an argument group with argparse's ``add_argument``;
        what is added there reaches that scheme's factory in ``context.options`` and is refused,
        with a message, when given with another transport. ``modalctl run``, ``emulate`` and
        ``identify`` carry these options; ``modalctl sweep`` reuses those of the ``sim`` scheme
        its (simulated) cases take. Use :func:`modalctl.units.quantity_type` for values with units.
    """


@hookspec
def modalctl_identifiers():
    """Return the modal parameter estimators this plugin provides.

    Returns
    -------
    iterable of modalctl.identify.estimators.Identifier
        Objects with ``name``, ``summary`` and ``identify(frf, threshold_db)`` returning
        :class:`modalctl.identify.estimators.Modes` (poles, modal constants per FRF row, misfit, resolved).
        Names must be unique across installed plugins.
    """


@hookspec
def modalctl_trackers():
    """Return the online resonance trackers this plugin provides (the identifiers' family).

    Returns
    -------
    iterable of modalctl.identify.trackers.TrackerFactory
        Objects with ``name``, ``summary`` and ``create(frequencies, damping, control_rate,
        **options)``; the tracker has ``update(response, drive)`` (lock-in envelopes, shape
        (k, m) complex), ``frequencies``, ``damping``, ``carriers`` and ``status`` per mode.
    """


@hookspec
def modalctl_controllers():
    """Return the per-mode controllers this plugin provides (the closed loop's low level).

    Returns
    -------
    iterable of modalctl.loops.controller.ControllerFactory
        Objects with ``name``, ``summary`` and ``create(plant, **options)``: ``plant`` is a
        :class:`modalctl.loops.controller.LoopPlant` (the modes, lock-in corners, rate, latency, noise);
        the controller has ``reset()``, ``update(error, limit)`` (envelope errors and command
        limits, shape (k,), in the carriers' frames; returns the commands), ``scale(factor)``
        and ``design`` (a :class:`modalctl.loops.controller.LoopDesign` for the report).
    """


@hookspec
def modalctl_commands():
    """Return the commands this plugin adds to the ``modalctl`` command line.

    Register the module under the entry point group ``modalctl.commands`` (not ``modalctl``):
    the command line loads that group alone before it parses, so keep the module's imports light.

    Returns
    -------
    iterable of modalctl.plugin.command.Command
        Objects with ``name``, ``help``, ``add_arguments(parser)`` and ``run(args) -> int``.
        Names must be unique across the command line.
    """
