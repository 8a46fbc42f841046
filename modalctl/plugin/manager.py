"""The plugin manager: loads plugins registered under the ``modalctl`` entry point group.

First-party plugins (``modalctl.plugins``) are registered through the same entry points as
third-party ones, so they are examples of what a plugin author writes.
"""

from __future__ import annotations

from functools import lru_cache

import pluggy

from modalctl.model.shape import ShapeGenerator

from . import spec as hookspecs

__all__ = ["PluginError", "plugin_manager", "shape_generators", "get_shape", "planners", "get_planner",
           "identifiers", "get_identifier", "trackers", "get_tracker", "controllers", "get_controller", "plugin_table",
           "pick", "name_of"]

ENTRY_POINT_GROUP = "modalctl"


class PluginError(LookupError):
    """An unknown or conflicting plugin name."""


@lru_cache(maxsize=None)
def plugin_manager() -> pluggy.PluginManager:
    """The process-wide plugin manager with every installed plugin loaded."""
    manager = pluggy.PluginManager(ENTRY_POINT_GROUP)
    manager.add_hookspecs(hookspecs)
    manager.load_setuptools_entrypoints(ENTRY_POINT_GROUP)
    return manager


def shape_generators(manager: pluggy.PluginManager | None = None) -> dict[str, ShapeGenerator]:
    """All installed shape generators by name."""
    return _by_name((manager or plugin_manager()).hook.modalctl_shapes(), "shape")


def get_shape(name: str, manager: pluggy.PluginManager | None = None) -> ShapeGenerator:
    """The shape generator called ``name``; the error lists the installed ones."""
    return _pick(shape_generators(manager), name, "shape")


def _pick(found: dict, name: str, kind: str):
    if name not in found:
        raise PluginError(f"unknown {kind} {name!r}; installed: {', '.join(found)}")
    return found[name]


def _by_name(groups, kind: str) -> dict:
    found: dict = {}
    for group in groups:
        for item in group:
            if item.name in found:
                raise PluginError(f"{kind} {item.name!r} is provided by two plugins")
            found[item.name] = item
    return dict(sorted(found.items()))


def planners(manager: pluggy.PluginManager | None = None) -> dict:
    """All installed planners (:class:`modalctl.plan.planner.Planner`) by name."""
    return _by_name((manager or plugin_manager()).hook.modalctl_planners(), "planner")


def get_planner(name: str, manager: pluggy.PluginManager | None = None):
    """The planner called ``name``; the error lists the installed ones."""
    return _pick(planners(manager), name, "planner")


def identifiers(manager: pluggy.PluginManager | None = None) -> dict:
    """All installed modal parameter estimators (:class:`modalctl.identify.estimators.Identifier`) by name."""
    return _by_name((manager or plugin_manager()).hook.modalctl_identifiers(), "identifier")


def get_identifier(name: str, manager: pluggy.PluginManager | None = None):
    """The estimator called ``name``; the error lists the installed ones."""
    return _pick(identifiers(manager), name, "identifier")


def trackers(manager: pluggy.PluginManager | None = None) -> dict:
    """All installed online trackers (:class:`modalctl.identify.trackers.TrackerFactory`) by name."""
    return _by_name((manager or plugin_manager()).hook.modalctl_trackers(), "tracker")


def get_tracker(name: str, manager: pluggy.PluginManager | None = None):
    """The tracker called ``name``; the error lists the installed ones."""
    return _pick(trackers(manager), name, "tracker")


def controllers(manager: pluggy.PluginManager | None = None) -> dict:
    """All installed per-mode controllers (:class:`modalctl.loops.controller.ControllerFactory`) by name."""
    return _by_name((manager or plugin_manager()).hook.modalctl_controllers(), "controller")


def get_controller(name: str, manager: pluggy.PluginManager | None = None):
    """The controller called ``name``; the error lists the installed ones."""
    return _pick(controllers(manager), name, "controller")


_FAMILIES = {"shape": shape_generators, "planner": planners, "identifier": identifiers, "tracker": trackers,
             "controller": controllers}


def pick(kind: str, choice, manager: pluggy.PluginManager | None = None):
    """The plugin object ``choice`` stands for: itself when it is an object (a planner, controller...
    a caller made), else the installed ``kind`` of that name (``kind``: shape, planner,
    identifier, tracker or controller). Names are resolved here, at the edge; the core calls objects."""
    if not isinstance(choice, str):
        return choice
    if kind not in _FAMILIES:
        raise ValueError(f"unknown plugin family {kind!r}; known: {', '.join(_FAMILIES)}")
    return _pick(_FAMILIES[kind](manager), choice, kind)


def name_of(choice) -> str:
    """The name a plugin choice goes by in records: the name given, or the object's ``name`` (its
    class name when it has none)."""
    if isinstance(choice, str):
        return choice
    return getattr(choice, "name", "") or type(choice).__name__


def plugin_table(manager: pluggy.PluginManager | None = None) -> list[dict]:
    """One row per registered plugin: its name, distribution and the hooks it implements."""
    manager = manager or plugin_manager()
    dists = {id(plugin): f"{dist.project_name} {dist.version}" for plugin, dist in manager.list_plugin_distinfo()}
    rows = []
    for name, plugin in manager.list_name_plugin():
        hooks = sorted(h.name for h in manager.get_hookcallers(plugin) or [])
        rows.append({"name": name, "distribution": dists.get(id(plugin), "-"), "hooks": hooks})
    return rows
