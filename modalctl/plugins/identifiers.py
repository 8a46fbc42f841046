"""First-party identifiers: offline, the thesis's peak picking and a local SDOF fit; online, an RLS tracker."""

from __future__ import annotations

from modalctl.identify.estimators import Identifier, peak_picking, sdof_fit
from modalctl.identify.trackers import PoleTracker, RLSTracker, TrackerFactory
from modalctl.plugin.spec import hookimpl


@hookimpl
def modalctl_identifiers():
    return [
        Identifier("peaks", "peak picking on the mean FRF, half-power damping, shapes at the peaks "
                            "(thesis chapter 3)", peak_picking),
        Identifier("sdof", "peak picking refined by a local single-mode least-squares fit of all FRFs "
                           "(close or heavily damped modes)", sdof_fit),
    ]


@hookimpl
def modalctl_trackers():
    return [TrackerFactory("rls", "per-mode recursive least squares on the lock-in envelopes, "
                                  "carriers retuned to the estimates", RLSTracker.create),
            TrackerFactory("pole", "per-mode recursive least squares on the pole, gain from the model: "
                                   "learns from any drive, a focus envelope included", PoleTracker.create)]
