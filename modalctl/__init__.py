"""modalctl: closed-loop control of vibration modes.

Start at :mod:`modalctl.api`, the front door: a researcher's path from a scene to a shot and every
contract a plugin implements, in one import (``from modalctl import api as mc``).

The layers, lowest first (``docs/architecture.md``): :mod:`~modalctl.model` (grids, modal models,
structures, scenes, shapes, metrics, the exact plant), :mod:`~modalctl.plan` (decomposition,
reduction, references, dispatch, planners), :mod:`~modalctl.loops` (lock-in, controllers,
runtime), :mod:`~modalctl.io` (the device contract and transports), :mod:`~modalctl.identify`,
then :mod:`~modalctl.run` (a shot end to end), :mod:`~modalctl.experiments`, :mod:`~modalctl.cli`;
:mod:`~modalctl.report` alone draws. Plugins hook in through :mod:`~modalctl.plugin`;
:mod:`~modalctl.hil` emulates the hardware.

Importing this package loads nothing else: the names below are imported on first use, so that
``modalctl --help`` and tools that only list plugins start at once.
"""

from importlib import import_module

__all__ = ["Grid", "ModalModel", "ModelError", "Shape", "Param", "Decomposition", "decompose"]
__version__ = "0.1.0"

_WHERE = {"Grid": "modalctl.model.modes", "ModalModel": "modalctl.model.modes", "ModelError": "modalctl.model.modes",
          "Shape": "modalctl.model.shape", "Param": "modalctl.model.shape",
          "Decomposition": "modalctl.plan.decompose", "decompose": "modalctl.plan.decompose"}


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module 'modalctl' has no attribute {name!r}")
    return getattr(import_module(_WHERE[name]), name)


def __dir__():
    return sorted([*globals(), *_WHERE])
