"""modalctl: closed-loop control of vibration modes.

The core computes (no ports, no figures): :mod:`~modalctl.model.modes` (grids, modal models, files),
:mod:`~modalctl.model.structures` (analytic beams and plates, piezo patches), :mod:`~modalctl.model.scenes`
(presets), :mod:`~modalctl.model.projection` (projection, Gram-Schmidt, cross-talk), :mod:`~modalctl.model.metrics`,
:mod:`~modalctl.plan.reduction`, :mod:`~modalctl.plan.decompose`. Plugins hook in through
:mod:`~modalctl.plugin.spec` and :mod:`~modalctl.plugin.manager`; pictures live in :mod:`~modalctl.report`.
"""

from modalctl.model.modes import Grid, ModalModel, ModelError
from modalctl.model.shape import Param, Shape
from modalctl.plan.decompose import Decomposition, decompose

__all__ = ["Grid", "ModalModel", "ModelError", "Shape", "Param", "Decomposition", "decompose"]
__version__ = "0.1.0"
