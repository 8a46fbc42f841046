"""First-party planners: ``envelope``, the thesis's exponential envelopes and their optimized rates;
``convex``, the whole drive as a quadratic program on the exact plant, the margin held on every
off-target point and DAC sample of the whole model.

The planners' modules are imported when a plan is made (the convex one loads its solver)."""

from __future__ import annotations

from modalctl.plan.planner import Planner
from modalctl.plugin.spec import hookimpl


class _Lazy(Planner):
    """A planner whose module is imported on first use."""

    def __init__(self, name: str, summary: str, module: str, cls: str):
        self.name, self.summary, self._where = name, summary, (module, cls)
        self._planner = None

    def plan(self, dec, focus_time, options, progress=False):
        return self._loaded().plan(dec, focus_time, options, progress)

    def feasible(self, dec, focus_time, options):
        return self._loaded().feasible(dec, focus_time, options)

    def _loaded(self) -> Planner:
        if self._planner is None:
            import importlib

            module, cls = self._where
            self._planner = getattr(importlib.import_module(module), cls)()
        return self._planner


@hookimpl
def modalctl_planners():
    return [_Lazy("envelope", "exponential envelopes at each kept mode's resonance (the thesis's Eqs 2.32-2.34), "
                              "their rates and brakes optimized for the margin on the kept modes (IPOPT), the "
                              "voltages corrected near T_F for the whole model (L-BFGS-B)",
                  "modalctl.plan.envelope", "EnvelopePlanner"),
            _Lazy("convex", "the whole drive as a quadratic program on the exact plant: each kept mode's envelope "
                            "on its carrier and every channel's fast drive near T_F, the margin on every off-target "
                            "point and DAC sample of the whole model, the least energy (DAQP)",
                  "modalctl.plan.convex", "ConvexPlanner")]
