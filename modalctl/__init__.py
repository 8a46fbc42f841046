"""modalctl: closed-loop control of vibration modes.

The core computes (no ports, no figures): :mod:`~modalctl.model` (grids, modal models, files),
:mod:`~modalctl.structures` (analytic beams and plates, piezo patches), :mod:`~modalctl.scenes`
(presets), :mod:`~modalctl.modal` (projection, Gram-Schmidt, cross-talk), :mod:`~modalctl.metrics`,
:mod:`~modalctl.reduction`, :mod:`~modalctl.decompose`. Plugins hook in through
:mod:`~modalctl.hookspecs` and :mod:`~modalctl.plugin`; pictures live in :mod:`~modalctl.report`.
"""

from .decompose import Decomposition, decompose
from .model import Grid, ModalModel, ModelError
from .shape import Param, Shape

__all__ = ["Grid", "ModalModel", "ModelError", "Shape", "Param", "Decomposition", "decompose"]
__version__ = "0.1.0"
