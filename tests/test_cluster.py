"""The cluster controller (issue 37, item 1): which kept modes read each other, the coupled envelope
model it designs on, and its loops on the HIL board against per-mode LQG."""

import json
from dataclasses import replace

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.signal import butter, lsim, sosfilt

from modalctl.loops.close_modes import Clusters, find_clusters
from modalctl.loops.cluster import ClusterControl, closed_loop_radius
from modalctl.loops.controller import Controller
from modalctl.loops.design import _series, cluster_model
from modalctl.loops.lockin import LockIn, Oscillators, lockin_bandwidths
from modalctl.loops.lqg import LQGControl
from modalctl.loops.schedule import HOLD, Schedule
from modalctl.loops.sensing import sensor_weights
from modalctl.model.propagate import Plant
from modalctl.model.scenes import load_scene
from modalctl.options import LoopOptions
from modalctl.plan.dispatch import dispatch

PAIR = (13, 14)  # plate-glass's labels 13 and 14: 8158 and 8278 Hz, 1.5% apart


@pytest.fixture(scope="module")
def plate():
    return load_scene("plate-glass")


def _bands(frequencies):
    """The loops' lock-in corners (Hz) with the run's default options."""
    options = LoopOptions()
    return lockin_bandwidths(frequencies, options.control_rate, options.lockin_fraction, options.lockin_image)


def _pair(model):
    return np.array([int(np.flatnonzero(model.labels == label)[0]) for label in PAIR])


def test_the_cluster_model_is_what_two_close_modes_demodulated_at_both_carriers_read(plate):
    """Loop 0 of a close pair steps its command on its carrier; the two modes' velocity simulated in time
    (scipy's lsim of each mode's equation, sensors, then each carrier's mixing and a digital Butterworth at
    1 MHz) against the model's step response in the driven loop's frame, turned to each loop's own: the
    neighbour's reading turns at the carriers' difference and passes its lock-in, as the model says."""
    pair = plate.select(_pair(plate))
    f, fs, t_end = pair.frequencies, 1e6, 15e-3
    bands = _bands(f)
    weights, sensors = dispatch(pair, [0, 1]), sensor_weights(pair, [0, 1])
    s = Schedule(20e3, 50, f, bands, sensors, *(np.zeros((2, 1)),) * 3, np.zeros((4, 1)), weights)
    t = np.arange(int(t_end * fs)) / fs
    command = 1e-3 * np.exp(0.7j)  # modal force envelope, N/sqrt(kg)
    volts = np.real(np.outer(weights[:, 0] * command, np.exp(2j * np.pi * f[0] * t)))  # (a, n)
    velocity = [lsim(([1, 0], [1, 2 * z * w, w**2]), force, t)[1]
                for w, z, force in zip(pair.omega, pair.damping, pair.actuator_gains @ volts)]
    sensed = sensors @ (pair.sensor_gains.T @ np.array(velocity))  # (2, n): each loop's sensor combination
    read = [sosfilt(butter(4, b, fs=fs, output="sos"), 2 * y * np.exp(-2j * np.pi * fc * t))
            for y, b, fc in zip(sensed, bands, f)]
    (a, b, c, d), filters, offsets = cluster_model(s, [0, 1], pair)
    a, b, c, d = _series((a, b, c, d), filters)
    late = t[::500][4:]  # from 2 ms (the lock-ins' start-up at the model's hold differs) every 0.5 ms
    x = np.array([np.linalg.solve(a, (expm(a * x) - np.eye(a.shape[0])) @ b[:, 0]) * command for x in late])
    model = (x @ c.T + d[:, 0] * command) * np.exp(-1j * np.outer(late, offsets))  # each loop's frame
    sim = np.array(read)[:, (late * fs).round().astype(int)].T
    assert np.abs(model[:, 1]).max() > 0.1 * np.abs(model[:, 0]).max()  # the neighbour reads a good part of it
    assert np.abs(model - sim).max() < 0.02 * np.abs(sim).max()
    unturned = x @ c.T + d[:, 0] * command  # read in the driven loop's frame only: not what the other reads
    assert np.abs(unturned[:, 1] - sim[:, 1]).max() > 0.3 * np.abs(sim[:, 1]).max()


def test_the_clusters_of_plate_glass_are_the_modes_whose_bands_meet(plate):
    """plate-glass's 21 modes (all kept by the closed loop's plan of the 30 mm Gaussian): with lock-in
    corners at the gap to the nearest mode (the default) the issue's 1.2% pair (modes 11 and 12), the 1.5%
    pair and the 5502/5943 Hz pair (which tests/test_truth.py shows holding less together than alone) are
    clusters; with corners at 0.4 of the gap the neighbour's motion, within its loop's crossover, falls
    outside every lock-in: no cluster."""
    from modalctl.loops.design import design_loops

    f = plate.frequencies
    for fraction, expect in ((1.0, True), (0.4, False)):
        bands = lockin_bandwidths(f, 20e3, fraction, 0.5)
        fc = design_loops(f, plate.damping, bands, 20e3).crossover_hz
        found = find_clusters(f, bands, fc)
        label = {int(plate.labels[i]): g for g in found.groups for i in g}
        for pair in ((11, 12), (13, 14), (9, 10)):
            assert (label.get(pair[0]) is not None and label.get(pair[0]) == label.get(pair[1])) == expect
        for i, j, spacing, threshold in found.pairs:
            assert spacing == pytest.approx(abs(f[i] - f[j]))
            assert threshold == pytest.approx(max(bands[i] + fc[j], bands[j] + fc[i]))
            assert (spacing < threshold) == any(i in g and j in g for g in found.groups)
        assert len(found.lines()) == len(found.pairs)


def _schedule_of(model) -> Schedule:
    """A schedule of a model's modes that holds only what the cluster's model needs: no shot, but
    a shot's length (500 periods: 25 ms at 20 kHz), over which a law must hold."""
    f, modes = model.frequencies, np.arange(model.n_modes)
    return Schedule(20e3, 25, f, _bands(f), sensor_weights(model, modes), *(np.zeros((f.size, 500)),) * 3,
                    np.zeros((model.actuator_gains.shape[1], 500)), dispatch(model, modes))


def test_a_neighbour_just_inside_or_outside_the_band_and_crossover_is_linked_or_not():
    bands, fc = np.array([100.0, 100.0, 100.0]), np.array([20.0, 20.0, 20.0])
    assert find_clusters([1000, 1119, 5000], bands, fc).groups == ((0, 1),)
    assert find_clusters([1000, 1121, 5000], bands, fc).groups == ()
    assert find_clusters([1000, 1110, 1220], bands, fc).groups == ((0, 1, 2),)  # a chain is one cluster


def _pair_shot(model, truth, steps, controller: str, periods: int = 400, authority: float = 2.0, latency: int = 0,
               lost=()):
    """The pair alone on the HIL board (no planner): a feed-forward that raises the modes in ``steps``
    (1 or 0 each) on their carriers, references read through the model as a schedule reads them, the
    loops of ``controller`` closing on ``truth``: the errors (periods, 2) the loops saw, the references'
    largest and the modes' velocity missed (the truth's less the planned, RMS over the shot's second half,
    relative to the planned's RMS there). The link ``latency`` periods late; the readings of the periods
    ``lost`` lost (the watchdog then tolerates two in a row)."""
    from modalctl.hil.phasor_board import BoardSetup, HILBoard
    from modalctl.loops.runtime import Runtime
    from modalctl.loops.shot import loop_sensing, parts_for
    from modalctl.loops.supervisor import Supervisor

    fs, rate = 500e3, 20e3
    options = LoopOptions(controller=controller, authority=authority, latency=latency, watchdog=3 if lost else 1)
    d, modes = int(fs / rate), np.array([0, 1])
    sensors, bands = loop_sensing(model, modes, options)
    weights = dispatch(model, modes)
    t = np.arange(periods * d) / fs
    rise = np.minimum(t / 4e-3, 1.0)
    forces = (2 * model.omega * model.damping * 0.01 * np.asarray(steps))[:, None] * rise  # holds 0.01 m/s sqrt(kg)
    phasors = Oscillators(model.frequencies, fs).phasors(t.size)
    volts = np.real(weights @ (forces * phasors))
    plant = Plant(model, fs, hold=HOLD)
    velocity = plant.step(volts)

    def lockin(x):
        return LockIn(bands, fs, d, closing=True).demodulate(x, phasors)

    reference, own = lockin(sensors @ plant.sensors(velocity)), lockin(velocity)
    s = Schedule(rate, d, model.frequencies, bands, sensors, reference, lockin(model.actuator_gains @ volts), own,
                 volts, weights)
    parts = parts_for(s, model, modes, options)
    logged = _Logged(parts.controller)
    parts.controller = logged
    class Lossy(HILBoard):
        def read(self):
            reading = super().read()
            return None if self.period - 1 in lost else reading  # the period just played

    board = Lossy(truth, fs, BoardSetup(latency=latency))
    result = Runtime(board, parts, Supervisor(parts.limits, s, np.abs(reference).max(axis=1) * 10, lead=parts.lead)).run()
    assert result.reason is None
    half = slice(t.size // 2, None)
    rms = lambda x: np.sqrt(np.mean(x[:, half] ** 2))  # noqa: E731
    missed = rms(board.velocity - velocity) / rms(velocity)
    return np.array(logged.errors), np.abs(reference).max(), missed


class _Logged(Controller):
    """A controller that keeps the errors it is given."""

    def __init__(self, inner):
        self.inner, self.design, self.observes, self.errors = inner, inner.design, inner.observes, []

    def reset(self):
        self.inner.reset()

    def observe(self, period, envelope, sent):
        self.inner.observe(period, envelope, sent)

    def update(self, error, limit):
        self.errors.append(np.array(error))
        return self.inner.update(error, limit)


ONE_ALONE = pytest.mark.xfail(strict=True, reason="measured: driving the lower mode alone, the cluster's loops miss "
                              "0.62 of its velocity where per-mode LQG misses 0.56 (PI 0.43): the joint law spends "
                              "the upper loop against the lower mode's share of its reading (an LQ cost on the modes' "
                              "own velocity envelopes instead of the readings: 0.60-0.62, no better)")


@pytest.mark.parametrize("steps", [pytest.param((1, 0), marks=ONE_ALONE), (0, 1), (1, 1)])
def test_a_close_pair_driven_one_by_one_and_together_is_tracked_at_least_as_well_as_by_per_mode_lqg(plate, steps):
    """The 1.5% pair with 1% more stiffness and 30% more damping in the truth than in the model: what the
    modes' velocity misses of the planned (RMS over the shot's second half) with the cluster's loops (one
    observer and one law on both) is no more than with per-mode LQG's, except when the lower mode alone
    is driven (xfail, measured)."""
    model = plate.select(_pair(plate))
    truth = replace(model, frequencies=model.frequencies * 1.01, damping=model.damping * 1.3)
    missed = {controller: _pair_shot(model, truth, steps, controller)[2] for controller in ("lqg", "cluster")}
    assert missed["cluster"] <= missed["lqg"], missed


def _innovation_ratio(model, monkeypatch, latency: int = 0, lost=()) -> float:
    """The nominal pair on the board with a random command (held 10 periods, as large as the drive) added to
    the loops' every period: the largest innovation of the cluster's observer over the largest error (from
    the 22nd reading on)."""
    dither = np.random.default_rng(0).standard_normal((40, 2, 2)) @ np.array([1, 1j]) * 0.3
    seen = []

    def dithered(self, error, limit):
        seen.append((np.array(error), self.inner.innovation.copy()))
        return self.inner.update(error, limit) + dither[(len(seen) - 1) // 10]

    monkeypatch.setattr(_Logged, "update", dithered)
    _pair_shot(model, model, (1, 1), "cluster", authority=1e6, latency=latency, lost=lost)
    error = np.array([e for e, _ in seen[21:]])
    innovation = np.array([i for _, i in seen[21:]])
    return float(np.abs(innovation).max() / np.abs(error).max())


@pytest.mark.parametrize("latency", [0, 1, 2])
def test_the_observer_predicts_what_the_board_reads_of_a_pair_under_any_command_and_not_if_its_frames_turn_wrong(
        plate, monkeypatch, latency):
    """The nominal truth, the plan's references, and a random command (held 10 periods, as large as the
    drive) added to the loops' in every period, the link ``latency`` periods late (the board's and the
    design's): the cluster observer's one-period prediction of both readings (its innovation) is within
    0.1% of what the commands move them, on the HIL board's path (lock-ins at the DAC rate, the board's
    ramp, the runtime's leak, which it takes off the newest command sent, not the oldest in flight: that
    was 141% at latency 1, 146% at 2); with each loop's frame turned the wrong way (the cross terms at
    minus the carriers' difference) it is far off."""
    import modalctl.loops.cluster as cluster

    model = plate.select(_pair(plate))
    right = _innovation_ratio(model, monkeypatch, latency)
    assert right < 1e-3, right
    if latency == 0:
        design = cluster._design
        monkeypatch.setattr(cluster, "_design", lambda *a: replace(design(*a), offsets=-design(*a).offsets))
        wrong = _innovation_ratio(model, monkeypatch, latency)
        assert wrong > 0.1, wrong


@pytest.mark.parametrize("latency", [0, 1])
def test_readings_lost_move_the_observer_on_with_the_held_command(plate, monkeypatch, latency):
    """Every seventh reading lost from period 40 on, every third of those with the next (the runtime skips
    the law's update and holds the command): the observer's state moves on by its model over the periods
    lost. The pair's loops on the 1% stiffer, 30% more damped truth miss as much of the modes' velocity as
    without the losses (0.6633 and 0.6633 at latency 0; a stale prediction after each loss: 0.6816, and
    0.6645 to 0.6822 at latency 1), and on the nominal truth under random commands the innovation stays
    within 0.1% of the error (3.0% with the stale step)."""
    model = plate.select(_pair(plate))
    lost = {n for n in range(40, 390) if n % 7 == 3} | {n + 1 for n in range(40, 390) if n % 21 == 3}
    truth = replace(model, frequencies=model.frequencies * 1.01, damping=model.damping * 1.3)
    steady = _pair_shot(model, truth, (1, 1), "cluster", latency=latency)[2]
    losing = _pair_shot(model, truth, (1, 1), "cluster", latency=latency, lost=lost)[2]
    assert losing < 1.005 * steady, (steady, losing)
    ratio = _innovation_ratio(model, monkeypatch, latency, lost)
    assert ratio < 1e-3, ratio


def test_with_no_close_modes_the_controller_is_per_mode_lqg(plate):
    """Lock-in corners at 0.4 of the gaps: no cluster on plate-glass's kept modes, and the cluster
    controller's commands are per-mode LQG's, period after period, limits biting or not."""
    from modalctl.loops.controller import LoopPlant
    from modalctl.loops.design import design_loops

    kept = np.array([0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 12, 13, 15, 16, 19, 20])
    bands = lockin_bandwidths(plate.frequencies, 20e3, 0.4, 0.5)[kept]
    plant = LoopPlant(plate.frequencies[kept], plate.damping[kept], bands, 20e3, noise=np.full(kept.size, 1e-4),
                      level=np.full(kept.size, 0.01), model=plate, modes=kept)
    assert find_clusters(plant.frequencies, bands, design_loops(plant.frequencies, plant.damping, bands,
                                                                20e3).crossover_hz).groups == ()
    cluster, lqg = ClusterControl(plant), LQGControl(plant)
    assert cluster.clusters.groups == () and not cluster.laws
    rng = np.random.default_rng(1)
    for n in range(50):
        error = 1e-3 * (rng.standard_normal(kept.size) + 1j * rng.standard_normal(kept.size))
        limit = np.full(kept.size, 1e-3 if n % 7 else 1e-9)
        cluster.observe(n, error, np.zeros(kept.size))
        assert np.array_equal(cluster.update(error, limit), lqg.update(error, limit))


def _simulated_rate(controller: ClusterControl, periods: int, start: int, truth=None) -> float:
    """The controller's update closing the loop on its one cluster's own model (the law's ``A, B, C``: the
    plant, the commands in flight, the readings less the runtime's leak), or on ``truth`` (another
    structure's ``A, B, C`` in the law's frame), from a random plant state, told the period and the commands
    sent, each loop's reading and command turned to and from its own frame as the board's: the plant
    state's growth per period from ``start`` to the end (below 1: it decays)."""
    law = controller.laws[0]
    a, b, c = (law.A, law.B, law.C) if truth is None else truth
    spin = np.exp(1j * law.offsets / 20e3)
    x, modes = np.zeros(a.shape[0]), a.shape[0] - law.lead * c.shape[0]
    x[:modes] = np.random.default_rng(5).standard_normal(modes)
    sent, norms = np.zeros(2, complex), []
    for n in range(periods):
        now = spin ** (n + 1)  # the reading of period n, at the model's (n + 1) T
        reading = (c @ x).view(complex) / now
        controller.observe(n, reading, sent)
        sent = controller.update(-reading, np.full(2, np.inf))
        x = a @ x + b @ (sent * now * spin ** law.lead).view(float)
        norms.append(np.linalg.norm(x))
    return float((norms[-1] / norms[start]) ** (1 / (periods - 1 - start)))


def test_each_clusters_nominal_loop_decays_at_its_spectral_radius_and_past_its_margin_grows(plate):
    """The controller's own update closing the loop on its cluster's nominal model (not the block matrix of
    closed_loop_radius): from a random state it decays per period at the spectral radius the controller
    reports (0.99896: the integrators); every gain times 300 (the radius crosses 1 between 100 and 200) it
    grows, at that law's radius. A plant without its model refuses clusters."""
    from modalctl.loops.controller import LoopPlant

    model = plate.select(_pair(plate))
    plant = LoopPlant(model.frequencies, model.damping, _bands(model.frequencies), 20e3)
    with pytest.raises(ValueError, match="model"):
        ClusterControl(plant, Clusters(((0, 1),), ()))
    assert ClusterControl(plant).laws == []
    controller = ClusterControl(_pair_plant(model))
    assert controller.clusters.groups == ((0, 1),) and controller.inner is None  # no per-mode LQG on a cluster
    rate = _simulated_rate(controller, 16000, 14000)  # two slow modes close: 3000 periods in, 0.99921
    assert rate < 1 and rate == pytest.approx(controller.spectral_radius[0], abs=1e-6)
    scaled = ClusterControl(_pair_plant(model))
    scaled.scale(300.0)
    law = scaled.laws[0]
    radius = closed_loop_radius(replace(law, K=law.K * 300, Ki=law.Ki * 300))
    assert 1.5 < radius == pytest.approx(_simulated_rate(scaled, 60, 30), rel=1e-3)


def test_the_cluster_law_takes_out_a_steady_error_the_feed_forward_leaves(plate):
    """The truth 30% more damped than the model: the error's mean over the last three beats of the pair
    (the part the loops' integrators can take out) on the loop the law can read (loop 0: loop 1 sees the
    other mode 1.1 times its own, above the leak limit 0.5, and rests), from 0.083 of the reference without feedback (authority 0) to 0.048 after 2400
    periods (the integrators are slow: the radius 0.99896 is 48 ms; PI: 5e-6). The nominal truth (the
    test before) gave no error with or without a law."""
    model = plate.select(_pair(plate))
    truth = replace(model, damping=model.damping * 1.3)
    beats = int(round(3 * 20e3 / abs(np.diff(model.frequencies)[0])))
    steady = {}
    for authority in (0.0, 2.0):
        errors, level, _ = _pair_shot(model, truth, (1, 1), "cluster", periods=2400, authority=authority)
        steady[authority] = np.abs(errors[-beats:].mean(axis=0)) / level
    assert steady[0.0][0] > 0.05 and steady[2.0][0] < 0.7 * steady[0.0][0], steady


def test_as_another_controllers_inner_loops_it_counts_the_periods_itself(plate):
    """A controller over them that does not tell them the period: untold, the cluster's laws count their
    updates and take their own commands for those sent, and command what a told one commands."""
    model = plate.select(_pair(plate))
    plant = _pair_plant(model)
    told, untold = ClusterControl(plant), ClusterControl(plant)
    rng = np.random.default_rng(2)
    sent = np.zeros(2, complex)
    for n in range(30):
        error = 1e-3 * (rng.standard_normal(2) + 1j * rng.standard_normal(2))
        told.observe(n, error, sent)
        sent = told.update(error, np.full(2, 1e-2))
        assert np.allclose(untold.update(error, np.full(2, 1e-2)), sent, rtol=1e-9, atol=1e-15)
    assert np.abs(sent).max() > 0


def test_the_touch_controller_tells_the_cluster_laws_what_was_sent_but_the_force_it_gives_back_where_checked(plate):
    """Over the cluster's laws, the touch controller passes on the period and the commands sent (a random
    force added to them here), less the force it gives back on the loops its estimator learns from (there
    the estimator checks it: the laws take it for the touch's drain it cancels); on the others (loop 1
    here, too leaky to learn from) the laws are told it. With a sure touch of 1 N s/m, the touch
    controller commands what laws told so command plus that force. Untold everywhere (the laws reading
    the force as a disturbance), plate-glass's resting finger was given back 72% (margin 0.549); told
    everywhere, the clamped plate's and panel-rounded's 95% and 77% (touch over PI 98% and 81%)."""
    from modalctl.loops.touch import TouchControl
    from modalctl.loops.touch_estimator import TouchEstimate
    from modalctl.model.touch import velocity_residues

    model = plate.select(_pair(plate))
    plant = _pair_plant(model)
    velocity = np.array([[0.01], [0.02j]])
    plant = replace(plant, schedule=replace(plant.schedule, velocity=velocity), shapes=model.shapes,
                    leaks=np.array([0.0, 1.0]))
    touch, told = TouchControl(plant, ClusterControl(plant)), ClusterControl(plant)
    assert touch.learned.tolist() == [0]
    index = int(np.argmax(np.abs(model.shapes[0] * model.shapes[1])))  # a place that both modes feel

    class Sure:  # an estimator sure of 1 N s/m there, and of no drift
        estimate = TouchEstimate(1.0, 0.0, index, 1.0, 1.0)

        def update(self, *args):
            pass

        def detuning(self):
            return np.zeros(1)

        def dampings(self):  # the shortest and longest memories agree: a touch that stays (no lift)
            return 1.0, 1.0

    touch.estimator = Sure()
    given = model.shapes[:, index] ** 2 / 2 * velocity[:, 0] / velocity_residues(model.frequencies, model.damping)
    assert np.abs(given).min() > 0
    rng = np.random.default_rng(3)
    sent, previous = np.zeros(2, complex), np.zeros(2, complex)
    for n in range(30):
        error = 1e-3 * (rng.standard_normal(2) + 1j * rng.standard_normal(2))
        touch.observe(n, np.zeros(2, complex), sent)
        told.observe(n, np.zeros(2, complex), sent - np.where(n > 0, [1, 0], 0) * given)
        command = touch.update(error, np.full(2, 1e-2))
        previous = told.update(error, np.full(2, 1e-2))
        assert np.allclose(command, previous + given, rtol=1e-9, atol=1e-15)
        sent = command + 1e-2 * (rng.standard_normal(2) + 1j * rng.standard_normal(2))  # a force added to it
    assert np.abs(previous).max() > 0


def test_the_clusters_say_which_modes_and_why_in_words_and_in_numbers():
    bands, fc = np.array([100.0, 100.0, 100.0]), np.array([20.0, 20.0, 20.0])
    linked = find_clusters([1119, 1000, 5000], bands, fc)
    assert linked.summary(["b", "a", "c"]) == ["modes a, b: a-b 119.0 Hz apart, below 120.0"]  # in frequency order
    numbers = linked.to_dict(["b", "a", "c"])
    assert numbers["groups"] == [["b", "a"]]
    assert {(tuple(p["modes"]), p["linked"]) for p in numbers["pairs"]} == {(("b", "a"), True), (("b", "c"), False)}
    apart = find_clusters([1000, 1121, 5000], bands, fc)
    assert apart.summary() == ["no cluster: the nearest to one, modes 0 and 1, 121.0 Hz apart, above 120.0 Hz"]


def test_the_margin_rule_links_a_pair_where_its_lock_ins_pass_more_than_its_gain_margin():
    """The threshold's spacing is where the two lock-ins' responses (design.lockin_filter's, evaluated)
    multiply to 1 - 10^(-GM/20) with the smaller gain margin GM; a pair a hertz inside it is linked, a hertz
    outside not; loops with more margin link less far."""
    import control

    from modalctl.loops.design import lockin_filter

    bands, fc, margins = np.array([100.0, 150.0, 100.0]), np.array([20.0, 30.0, 20.0]), np.array([6.0, 8.0, 6.0])
    far = find_clusters([1000, 5000, 9000], bands, fc, margins)
    threshold = far.pairs[0][3] - 30.0  # less the larger crossover: the spacing where the lock-ins meet the margin
    gain = np.prod([abs(complex(control.evalfr(lockin_filter(b), 2j * np.pi * threshold))) for b in bands[:2]])
    assert gain == pytest.approx(1 - 10 ** (-6 / 20), rel=1e-6)
    edge = far.pairs[0][3]
    assert find_clusters([1000, 1000 + edge - 1, 9000], bands, fc, margins).groups == ((0, 1),)
    assert find_clusters([1000, 1000 + edge + 1, 9000], bands, fc, margins).groups == ()
    assert find_clusters([1000, 5000, 9000], bands, fc, margins + 6).pairs[0][3] < edge


@pytest.mark.parametrize("error", [
    np.linalg.LinAlgError("The associated symplectic pencil has eigenvalues too close to the unit circle"),
    ValueError("Reordering of (A, B) failed because the transformed matrix pair (A, B) would be too far from "
               "generalized Schur form; the problem is very ill-conditioned.")])
def test_a_cluster_whose_observer_has_no_solution_keeps_per_mode_loops(plate, monkeypatch, error):
    """dlqe or dlqr refusing a cluster (panel-rounded's modes 30-31 under the margin rule: dlqe's pencil with
    every near mode observed, dlqr's reordering (scipy's ValueError) with the modes near it: the run ended
    in an error): the controller says so and those modes are per-mode LQG's, period after period. Another
    ValueError (a fault of the design's own) is not taken for a refusal."""
    import modalctl.loops.cluster as cluster

    def refuse(*args):
        raise error

    def fails(*args):
        raise ValueError("operands could not be broadcast together with shapes (4,) (6,)")

    solved = cluster._solved  # the clusters' dlqr and dlqe go through it (the isolated loops' LQG does not)
    plant = _pair_plant(plate.select(_pair(plate)))
    if isinstance(error, ValueError):
        monkeypatch.setattr(cluster, "_solved", lambda riccati, *matrices: solved(fails, *matrices))
        with pytest.raises(ValueError, match="broadcast"):
            ClusterControl(plant)
    monkeypatch.setattr(cluster, "_solved", lambda riccati, *matrices: solved(refuse, *matrices))
    controller, lqg = ClusterControl(plant), LQGControl(plant)
    assert controller.clusters.groups == () and [g for g, _ in controller.refused] == [(0, 1)]
    rng = np.random.default_rng(4)
    for n in range(20):
        error = 1e-3 * (rng.standard_normal(2) + 1j * rng.standard_normal(2))
        controller.observe(n, error, np.zeros(2))
        assert np.array_equal(controller.update(error, np.full(2, 1e-2)), lqg.update(error, np.full(2, 1e-2)))


@pytest.mark.parametrize("controller, together", [(None, True), ("cluster", True), ("touch", False)])
def test_a_closed_loop_run_reports_the_clusters_whatever_the_controller(tmp_path, capsys, controller, together):
    """metrics.json's loop.clusters: the kept modes (labels) whose loops read each other, every pair's carrier
    spacing (the model's frequencies) against the rule's threshold, the groups the linked pairs join;
    the printed summary says them, and whether the controller controls them as one."""
    from modalctl.cli import main

    args = ["run", "--scene", "thesis-al-cc", "--points", "211", "--shape", "bump", "--param", "width=25mm",
            "--focus-time", "25ms", "--no-plots", "--loop", "closed", "--out", str(tmp_path / "r")]
    assert main(args + ([] if controller is None else ["--controller", controller])) == 0
    printed = capsys.readouterr().out
    clusters = json.loads((tmp_path / "r" / "metrics.json").read_text())["loop"]["clusters"]
    model = load_scene("thesis-al-cc", 211)
    frequency = {int(label): f for label, f in zip(model.labels, model.frequencies)}
    assert clusters["together"] is together and clusters["groups"]  # al-cc's gaps are its lock-ins' corners
    for pair in clusters["pairs"]:
        a, b = pair["modes"]
        assert pair["spacing_hz"] == pytest.approx(abs(frequency[a] - frequency[b]))
        assert pair["linked"] == (pair["spacing_hz"] < pair["threshold_hz"])
    group_of = {m: i for i, group in enumerate(clusters["groups"]) for m in group}
    for pair in (p for p in clusters["pairs"] if p["linked"]):  # a linked pair lies in one group
        a, b = pair["modes"]
        assert a in group_of and group_of[a] == group_of.get(b)
    for group in clusters["groups"]:  # every mode of a group is linked to another of it
        linked = {m for p in clusters["pairs"] if p["linked"] and set(p["modes"]) <= set(group) for m in p["modes"]}
        assert linked == set(group)
    assert "clusters (" in printed and all(line in printed for line in clusters["lines"])
    assert ("each controlled as one" in printed) is together


def _pair_plant(model, drift: float = 0.01):
    from modalctl.loops.controller import LoopPlant

    k = model.n_modes
    return LoopPlant(model.frequencies, model.damping, _bands(model.frequencies), 20e3, level=np.full(k, 0.01),
                     noise=np.full(k, 1e-4), drift=drift, model=model, modes=np.arange(k), schedule=_schedule_of(model))


PERIODS = 40000  # the 5% band's worst mode grows by 1.8e-4 a period: 16,000 periods read it within 9e-6 only


@pytest.mark.parametrize("drift", [0.01, 0.05, 0.07])
def test_a_cluster_law_is_kept_only_where_it_holds_over_the_drift_band(plate, drift):
    """drift_radius against the controller's own update closing the loop on the pair drifted to the band's
    worst case (the structure's model in the law's frame, not the block matrix): the same growth per
    period. Over +-1% the pair's law holds (the worst radius below 1) and is kept; over +-5% the law
    designed for that band grows by 2.5% over the shot's 500 periods at -5% (radius 1.00005, within
    ``GROWTH``) and is kept; over +-7% it grows 770-fold: the controller keeps per-mode LQG's loops on
    the pair, commands to the bit, and says why."""
    from modalctl.loops.cluster import GROWTH, _frame, _observed_model, drift_radius

    pair = plate.select(_pair(plate))
    plant = _pair_plant(pair, drift)
    controller, lqg = ClusterControl(plant), LQGControl(plant)
    if drift < 0.07:
        kept = ClusterControl(_pair_plant(pair, 0.0))  # no band to hold: its law is kept, whatever it does at a drift
        law = kept.laws[0]
        radius, worst = drift_radius(plant, law)
        assert abs(worst) in (drift, drift / 2)
        truth = _observed_model(replace(plant, model=pair.drifted(worst)), law.loops, _frame(plant, law.loops))[:3]
        assert _simulated_rate(kept, PERIODS, PERIODS - 2000, truth) == pytest.approx(radius, abs=1e-6)
        assert controller.clusters.groups == ((0, 1),) and not controller.refused
        held = drift_radius(plant, controller.laws[0])[0]
        assert held < 1 if drift == 0.01 else 1 < held ** plant.schedule.reference.shape[1] <= GROWTH
        return
    assert controller.clusters.groups == () and controller.clusters.refused == tuple(controller.refused)
    assert [g for g, _ in controller.refused] == [(0, 1)]
    assert "7% drift (spectral radius 1.0" in controller.refused[0][1]
    assert controller.clusters.summary()[0].startswith("modes 0, 1: per-mode loops, its law unstable at")
    rng = np.random.default_rng(4)
    for n in range(20):
        error = 1e-3 * (rng.standard_normal(2) + 1j * rng.standard_normal(2))
        controller.observe(n, error, np.zeros(2))
        assert np.array_equal(controller.update(error, np.full(2, 1e-2)), lqg.update(error, np.full(2, 1e-2)))


@pytest.mark.parametrize("lead", [1, 2, 3])
def test_a_pi_loops_poles_are_those_of_its_pi_closed_on_the_observers_model(plate, lead):
    """design.cluster_poles against an independent construction: the runtime's PI (``kp e`` plus the sum of
    ``ki T e``) closed by hand on the cluster observer's discrete model of one loop of the 1.5% pair, its sensors reading
    the other mode too (the model
    the observer test checks against the HIL board at every latency: the runtime's leak off the command last
    sent, after the lock-in), lead 1-3, at the designed gains and twice them: the same poles (to 1e-12). Taking
    the leak off before the lock-in on the command the plant takes (before) put the largest |z| 0.007 off at
    the designed gains (1.0063 for 1.0057 at lead 1) and 0.7 off at twice them (1.014 for 1.741). (The loop's
    reading sees mode 0 so much that even its designed gains grow: what the runtime's leak limit is for.)"""
    from types import SimpleNamespace

    import modalctl.loops.cluster as cluster
    from modalctl.loops.design import cluster_poles, design_loops
    from modalctl.loops.sensing import feedthrough

    model = plate.select(_pair(plate))
    plant = _pair_plant(model)
    s = plant.schedule
    s = replace(s, sensors=s.sensors + np.array([[0.0], [1.0]]) * s.sensors[::-1])  # loop 1 reads mode 0 too
    plant, period = replace(plant, latency=float(lead), schedule=s), 1 / plant.control_rate
    design = design_loops(plant.frequencies, plant.damping, plant.bandwidths, plant.control_rate, latency=lead)
    leak = feedthrough(model, np.array([0, 1]), s.sensors, s.weights)
    assert abs(leak[1]) > 5 * abs(leak[0])  # loop 1's own command leaks into its reading (through mode 0)
    parts = SimpleNamespace(schedule=s, design=design, leak=leak, lead=lead)
    a, b, c = cluster._observed_model(plant, np.array([1]), s.carriers[1])[:3]
    for scale in (1.0, 2.0):
        kp, ki = scale * design.kp[1], scale * design.ki[1] * period
        closed = np.block([[a - (kp + ki) * b @ c, ki * b], [-c, np.eye(2)]])  # (x, the sum of e before this one)
        by_hand = np.sort(np.abs(np.linalg.eigvals(closed)))[::-1][:6]
        poles = np.sort(np.abs(np.exp(cluster_poles(parts, [1], model, scale) * period)))[::-1][:6]
        assert poles == pytest.approx(by_hand, rel=1e-6, abs=1e-9)


def test_a_rule_the_controller_does_not_know_is_refused(plate):
    from modalctl.loops.controller import LoopPlant

    kept = np.arange(3)
    bands = lockin_bandwidths(plate.frequencies, 20e3, 0.4, 0.5)[kept]
    plant = LoopPlant(plate.frequencies[kept], plate.damping[kept], bands, 20e3)
    with pytest.raises(ValueError, match="rule must be 'margin' or 'band', got 'margn'"):
        ClusterControl(plant, rule="margn")


@pytest.mark.parametrize("drift", [-0.01, 0.6, float("nan")])
def test_a_drift_the_loops_cannot_expect_is_refused_naming_it(drift):
    """The loops' expected drift moves the model the cluster laws are checked on: negative, past half
    the resonance (a model with resonances at zero or below) or NaN is refused as bad input."""
    from modalctl.errors import InputError

    assert LoopOptions(drift=0.0).drift == 0.0 and LoopOptions(drift=0.5).drift == 0.5
    with pytest.raises(InputError, match="drift must lie in"):
        LoopOptions(drift=drift)


def test_the_laws_designed_in_a_forked_child_are_those_designed_here(plate, monkeypatch):
    """From ``BESIDE`` clusters on, about half the laws are designed in a forked child: plate-glass's first ten
    modes in five pairs, the child asked once, its laws (every matrix, to the bit) and refusals those this
    process designs alone, in the groups' order."""
    import modalctl.loops.cluster as cluster

    plant = _pair_plant(plate.select(np.arange(10)))
    groups = Clusters(tuple((i, i + 1) for i in range(0, 10, 2)), ())
    asked, fork = [], cluster.beside
    monkeypatch.setattr(cluster, "beside", lambda job: asked.append(job) or fork(job))
    beside = ClusterControl(plant, groups)
    monkeypatch.setattr(cluster, "BESIDE", len(groups.groups) + 1)
    here = ClusterControl(plant, groups)
    assert len(asked) == 1 and len(beside.laws) + len(beside.refused) == 5
    assert beside.clusters == here.clusters and beside.refused == here.refused
    for ours, theirs in zip(beside.laws, here.laws, strict=True):
        for name in ("loops", "A", "B", "C", "M", "K", "Ki", "turn", "offsets"):
            assert np.array_equal(getattr(ours, name), getattr(theirs, name)), name


def test_an_error_in_this_processs_half_of_the_laws_stops_the_child_designing_the_other(monkeypatch):
    """What the laws designed here raise is raised, and the forked child designing the rest is stopped, not left
    behind (a Ctrl-C there alike)."""
    import modalctl.loops.cluster as cluster

    children, fork = [], cluster.beside
    monkeypatch.setattr(cluster, "beside", lambda job: children.append(fork(job)) or children[-1])

    def judge(group):
        if group == (0, 1):  # the largest first, to this process
            raise ValueError("a fault of the design's own")
        return group

    groups = tuple((i, i + 1) for i in range(0, 10, 2))
    with pytest.raises(ValueError, match="own"):
        cluster._judged_beside(groups, judge)
    assert len(children) == 1 and children[0]._process is None  # stopped: killed and joined
    assert cluster._judged_beside(groups, lambda group: group) == list(groups)


def test_a_cluster_s_observer_does_not_depend_on_the_units_of_its_noises(plate):
    """The Kalman gain depends on the process and the measurement noise only through their ratio: the pair's
    law with the planned level and the sensors' noise both 10^3 and 10^6 times smaller is the same observer.
    Solved in absolute units scipy's reordering of the Riccati pencil gave 1.150 for the gain's largest entry
    at 10^-3 (1.138 at 1) and failed from 10^-4 on (the cluster then left to per-mode loops: plate-glass's modes
    42-43 in a closed loop of its 30 mm bump at (-20, 5) mm)."""
    model = plate.select(_pair(plate))
    base = _pair_plant(model)
    gains = []
    for scale in (1.0, 1e-3, 1e-6):
        controller = ClusterControl(replace(base, level=base.level * scale, noise=base.noise * scale))
        assert controller.refused == [] and len(controller.laws) == 1
        gains.append(controller.laws[0].M)
    for other in gains[1:]:
        assert np.allclose(other, gains[0], rtol=1e-6, atol=1e-9)
