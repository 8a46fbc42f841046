"""First-party identifiers: offline, the thesis's peak picking, a local SDOF fit, LSCF (MDOF) and
``auto`` (SDOF where it resolves, MDOF elsewhere); online, RLS trackers.

Each is a subclass of its contract (:class:`~modalctl.identify.estimators.Identifier`,
:class:`~modalctl.identify.trackers.TrackerFactory`), as a third party's would be."""

from __future__ import annotations

from modalctl.identify.estimators import Identifier, peak_picking, sdof_fit
from modalctl.identify.mdof import auto_fit, mdof_fit
from modalctl.identify.trackers import PoleTracker, RLSTracker, TrackerFactory
from modalctl.plugin.spec import hookimpl


class Peaks(Identifier):
    name = "peaks"
    summary = "peak picking on the mean FRF, half-power damping, shapes at the peaks (thesis chapter 3)"

    def identify(self, frf, threshold_db=3.0):
        return peak_picking(frf, threshold_db=threshold_db)


class SDOF(Identifier):
    name = "sdof"
    summary = "peak picking refined by a local single-mode least-squares fit of all FRFs (separated modes; " \
              "robust to noise)"

    def identify(self, frf, threshold_db=3.0):
        return sdof_fit(frf, threshold_db=threshold_db)


class MDOF(Identifier):
    name = "mdof"
    summary = "LSCF stabilization over octave bands, poles picked automatically and refined, LSFD constants " \
              "(close and heavily damped modes, shoulders)"

    def identify(self, frf, threshold_db=3.0):
        return mdof_fit(frf, threshold_db=threshold_db)


class Auto(Identifier):
    name = "auto"
    summary = "sdof where one pole explains a peak, mdof everywhere else"

    def identify(self, frf, threshold_db=3.0):
        return auto_fit(frf, threshold_db=threshold_db)


class RLS(TrackerFactory):
    name = "rls"
    summary = "per-mode recursive least squares on the lock-in envelopes, carriers retuned to the estimates"

    def create(self, frequencies, damping, control_rate, **options):
        return RLSTracker.create(frequencies, damping, control_rate, **options)


class Pole(TrackerFactory):
    name = "pole"
    summary = "per-mode recursive least squares on the pole, gain from the model: learns from any drive, a " \
              "focus envelope included"

    def create(self, frequencies, damping, control_rate, **options):
        return PoleTracker.create(frequencies, damping, control_rate, **options)


@hookimpl
def modalctl_identifiers():
    return [Peaks(), SDOF(), MDOF(), Auto()]


@hookimpl
def modalctl_trackers():
    return [RLS(), Pole()]
