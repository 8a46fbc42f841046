"""First-party identifiers: offline, the thesis's peak picking, a local SDOF fit, LSCF (MDOF) and
``auto`` (SDOF where it resolves, MDOF elsewhere); online, RLS trackers."""

from __future__ import annotations

from modalctl.identify.estimators import Identifier, peak_picking, sdof_fit
from modalctl.identify.mdof import auto_fit, mdof_fit
from modalctl.identify.trackers import PoleTracker, RLSTracker, TrackerFactory
from modalctl.plugin.spec import hookimpl


@hookimpl
def modalctl_identifiers():
    return [
        Identifier("peaks", "peak picking on the mean FRF, half-power damping, shapes at the peaks "
                            "(thesis chapter 3)", peak_picking),
        Identifier("sdof", "peak picking refined by a local single-mode least-squares fit of all FRFs "
                           "(separated modes; robust to noise)", sdof_fit),
        Identifier("mdof", "LSCF stabilization over octave bands, poles picked automatically and refined, "
                           "LSFD constants (close and heavily damped modes, shoulders)", mdof_fit),
        Identifier("auto", "sdof where one pole explains a peak, mdof everywhere else", auto_fit),
    ]


@hookimpl
def modalctl_trackers():
    return [TrackerFactory("rls", "per-mode recursive least squares on the lock-in envelopes, "
                                  "carriers retuned to the estimates", RLSTracker.create),
            TrackerFactory("pole", "per-mode recursive least squares on the pole, gain from the model: "
                                   "learns from any drive, a focus envelope included", PoleTracker.create)]
