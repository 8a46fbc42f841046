"""The loops' compiled kernels (modalctl.loops.kernels) against the numpy each replaced, written out here
as it was: the same commands, sums and forces to round-off, through the branches (saturation, anti-windup,
resting loops, deficits and surpluses, the quick bound passed and failed)."""

import numpy as np
import pytest

from modalctl.loops import kernels

RNG = np.random.default_rng(11)


def _complex(*shape):
    return RNG.standard_normal(shape) + 1j * RNG.standard_normal(shape)


def _numpy_pi(kp, ki_period, integral, error, limit):
    """The vector PI law as numpy evaluated it: (command, next integral)."""
    proportional = kp * error
    trial = integral + ki_period * error
    command = proportional + trial
    outside = ~(np.abs(command) <= limit)
    held = ((np.conj(command) * error).real > 0) & outside
    trial = np.where(held, integral, trial)
    command = proportional + trial
    command = command * np.fmin(limit / (np.abs(command) + 1e-300), 1.0)
    live = limit > 0
    return command * live, trial * live


def test_pi_law_is_numpy_s_through_saturation_anti_windup_and_rest():
    k = 9
    kp, ki_period = RNG.uniform(50, 500, k), RNG.uniform(1e3, 1e5, k) / 20e3
    integral, reference = np.zeros(k, complex), np.zeros(k, complex)
    held = rested = clipped = 0
    for _ in range(400):
        error = _complex(k) * 1e-3
        limit = np.where(RNG.random(k) < 0.15, 0.0, RNG.uniform(0.05, 0.6, k))
        odd = RNG.random(k)
        limit[odd < 0.03], limit[odd > 0.97] = -0.2, np.nan  # a limit below zero or not a number: rest too
        expected, reference_next = _numpy_pi(kp, ki_period, reference, error, limit)
        command, before = np.empty(k, complex), integral.copy()
        kernels.pi_update(kp, ki_period, integral, error, limit, command)
        assert np.allclose(command, expected, rtol=1e-12, atol=1e-15)
        assert np.allclose(integral, reference_next, rtol=1e-12, atol=1e-15)
        held += np.count_nonzero((integral == before) & (limit > 0) & (error != 0))
        rested += np.count_nonzero(~(limit > 0))
        clipped += np.count_nonzero(np.isclose(np.abs(command), limit))
        reference = reference_next
    assert held > 20 and rested > 100 and clipped > 100  # every branch was exercised


def test_filter_step_is_the_state_space_product():
    k, o = 7, 4
    step = RNG.standard_normal((k, o + 1, o + 1))
    io = _complex(k, o + 1)
    expected = np.einsum("krc,kc->kr", step, io)  # [y; x'] = [[D, C], [B, A]] [u; x]
    out = np.empty(k, complex)
    kernels.filter_step(step, io, out)
    assert np.allclose(out, expected[:, 0], rtol=1e-13) and np.allclose(io[:, 1:], expected[:, 1:], rtol=1e-13)


@pytest.mark.parametrize("first", [0, 2])
def test_regression_step_is_the_estimator_s_einsums(first):
    k, m = 12, 6
    weights, inputs, new = _complex(3, 5, k + 1), _complex(5, k + 1), _complex(3, k)
    sums, keep = RNG.standard_normal((m, 2, 3, k + 1)), RNG.uniform(0.5, 1, m)
    written = inputs.copy()
    written[[first, first + 1, 4], :k] = new  # this period's envelope, drive and expected residual
    eh_expected = np.einsum("rjk,jk->rk", weights, written)
    parts = eh_expected.view(float).reshape(3, k + 1, 2)
    sums_expected = sums * keep[:, None, None, None] + np.einsum("ikc,jkc->ijk", parts[:2], parts)
    eh = np.empty((3, k + 1), complex)
    kernels.regression_step(weights, inputs, first, tuple(new), eh, sums, keep)
    assert np.array_equal(inputs, written)
    assert np.allclose(eh, eh_expected, rtol=1e-13) and np.allclose(sums, sums_expected, rtol=1e-13)


def test_noise_carry_is_the_numpy_recursion():
    m, k = 4, 10
    turn, stationary = _complex(m, k), RNG.uniform(1, 3, k)
    lam = RNG.uniform(0.8, 1, (m, 1))
    rho_lam = RNG.uniform(0, 1, k) * lam
    carried, crossed, last, h = RNG.random((m, k)), _complex(m, k), _complex(k), _complex(k)
    d = last - turn * h
    w = stationary * d + crossed
    carried_expected = (carried + (d.conj() * (w + crossed)).real) * lam ** 2
    crossed_expected = rho_lam * w
    kernels.noise_carry(turn, stationary, lam ** 2, rho_lam, last, h, carried, crossed)
    assert np.allclose(carried, carried_expected, rtol=1e-13) and np.allclose(crossed, crossed_expected, rtol=1e-13)
    assert np.array_equal(last, h)


@pytest.mark.parametrize("scale", [37.0, 0.0], ids=["before the focus", "from the focus on"])
def test_catch_up_period_is_its_numpy_steps(scale):
    """The envelopes' answer to the corrections, through the lock-in's filter, and the deficit along the plan
    caught up on the loops with authority, added to their commands; nothing from the focus on."""
    loops, k, o = 11, 7, 4
    modes = np.sort(RNG.choice(loops, k, replace=False)).astype(np.int64)
    error, limit, feedback = _complex(loops), np.where(RNG.random(loops) < 0.3, 0.0, 1.0), _complex(loops)
    model, state, last, playing = _complex(3, k), _complex(k), _complex(k), _complex(k)
    step, io, plan = RNG.standard_normal((k, o + 1, o + 1)), _complex(k, o + 1), _complex(2, k)
    moved = model[0] * state + model[1] * last + model[2] * playing
    through = np.einsum("krc,kc->kr", step, np.column_stack([moved, io[:, 1:]]))
    lost = error[modes] - moved + through[:, 0]
    along = np.maximum((lost * plan[0]).real, 0) * (limit[modes] > 0)
    expected_force = plan[1] * along * scale
    expected_feedback = feedback.copy()
    expected_feedback[modes] += expected_force
    out = np.empty(k, complex)
    kernels.catch_up_period((model, state, last, playing), (step, io), (error, limit, modes, feedback), plan, scale,
                            out)
    assert np.allclose(state, moved, rtol=1e-13) and np.allclose(io[:, 1:], through[:, 1:], rtol=1e-13)
    assert np.allclose(out, expected_force, rtol=1e-13) and np.allclose(feedback, expected_feedback, rtol=1e-13)
    assert (0 < np.count_nonzero(out) < k) if scale else not out.any()


def test_overlap_commands_solve_the_groups_and_pass_the_rest():
    k, index = 9, np.array([6, 1, 4], np.int64)
    forces, base, turn, inverse = _complex(k), _complex(k), np.exp(1j * RNG.uniform(0, 6, 3)), _complex(3, 3)
    expected = forces.copy()
    expected[index] = turn.conj() * (inverse @ (turn * forces[index]))
    out = np.empty(k, complex)
    kernels.overlap_commands(forces, base, index, turn, inverse, out)
    assert np.allclose(out, base + expected, rtol=1e-13)


@pytest.mark.parametrize("room_scale", [0.5, 2.0, 1e3])
def test_quick_bound_and_divergence_are_numpy_s(room_scale):
    k, a = 8, 3
    quick, size_old, new = RNG.random((2 * a, k)), RNG.random(k), _complex(k)
    bound = quick @ np.maximum(size_old, np.abs(new))
    room = bound * room_scale * RNG.uniform(0.9, 1.1, 2 * a)
    size_new = np.empty(k)
    within = kernels.quick_bound_within(quick, size_old, new, room, size_new)
    assert within == (not np.count_nonzero(bound > room)) and np.allclose(size_new, np.abs(new))
    level = np.abs(new) * room_scale
    assert kernels.over_any(new, level) == bool(np.count_nonzero(np.abs(new) > level))


def test_place_sums_are_the_estimator_s_weighted_sums():
    m, k, reads = 5, 9, 7.0
    sums, q = RNG.standard_normal((m, 2, 3, k + 1)), RNG.random(k)
    weights = np.zeros((k + 1, 4))  # q, q^2, the modes, the count (times the modes read): as it was
    weights[:-1, 0], weights[:-1, 1], weights[:-1, 2], weights[-1, 3] = q, q ** 2, 1.0, reads
    table = (sums.reshape(-1, k + 1) @ weights).reshape(m, 2, 3, 4)
    expected = [table[:, 0, 1, 0], table[:, 1, 1, 1], table[:, 0, 0, 2], table[:, 0, 0, 3]]
    out = np.empty((4, m))
    kernels.place_sums(sums, q, reads, out)
    assert np.allclose(out, expected, rtol=1e-12)
    sums[0, 1, 1] = np.abs(sums[0, 1, 1])  # |h|^2 sums: positive on the shortest memory,
    sums[-1, 1, 1] = -np.abs(sums[-1, 1, 1])  # not on the longest (no damping read there)
    expected = [np.einsum("k,mk->m", q, sums[:, 0, 1, :k]), np.einsum("k,mk->m", q ** 2, sums[:, 1, 1, :k])]
    short, long = kernels.place_dampings(sums, q)
    assert short == pytest.approx(-expected[0][0] / expected[1][0], rel=1e-12) and expected[1][0] > 0
    assert np.isnan(long) and not expected[1][-1] > 0


def test_warm_loads_every_kernel():
    kernels.warm()
    assert all(not isinstance(getattr(kernels, name), kernels._Kernel) for name in kernels.KERNELS)


def _numpy_cluster_period(cka, kam, ki, x, slot, sent, now, ahead, sent_ahead, error, limit, index, integral):
    """The stacked cluster laws' period as ClusterControl.update evaluated it in numpy (scipy's products):
    (commands of its loops, next state, integral, innovation)."""
    x, integral = x.copy(), integral.copy()
    played = now * ahead
    if sent.size:
        x[slot] = (sent[index] * now * sent_ahead).view(float)
    z = -error[index]
    predicted = cka @ x
    k2 = index.size * 2
    surprise = (z * now).view(float) - predicted[:k2]
    innovation = surprise.view(complex) / now
    joined = predicted[k2:] + kam @ surprise
    feedback, ahead_state = joined[:k2], joined[k2:]
    out = (-feedback - ki @ (integral * now).view(float)).view(complex) / played
    size, cap = np.abs(out), limit[index]
    over = size > cap
    out[over] *= cap[over] / np.maximum(size[over], 1e-300)
    integral = np.where(over, integral, integral + z)
    integral[cap <= 0] = 0
    ahead_state[slot] += (out * played).view(float)
    return out, ahead_state, integral, innovation


@pytest.mark.parametrize("sent", [True, False])
def test_cluster_period_is_the_numpy_update(sent):
    """Two laws stacked block-diagonally (5 loops of 9, 22 states), with a command in flight and without one
    (the first period), some loops over their limit and one resting: the commands, the next state, the
    integrals and the innovation of the update numpy made, to round-off."""
    from scipy import sparse
    from scipy.linalg import block_diag

    loops, states = 9, (12, 10)
    index = np.array([1, 4, 5, 7, 8])
    blocks = [(2, 12), (3, 10)]  # (loops, states) per law: its rows of C and K are 2 per loop
    dense = lambda rows, cols: RNG.standard_normal((rows, cols)) * (RNG.random((rows, cols)) < 0.4)  # noqa: E731
    c = block_diag(*(dense(2 * g, n) for g, n in blocks))
    k = block_diag(*(dense(2 * g, n) for g, n in blocks))
    a = block_diag(*(dense(n, n) * 0.3 for _, n in blocks))
    m = block_diag(*(dense(n, 2 * g) for g, n in blocks))
    ki = sparse.csr_array(block_diag(*(dense(2 * g, 2 * g) for g, _ in blocks)))
    cka, kam = sparse.csr_array(np.vstack([c, k, a])), sparse.csr_array(np.vstack([k, a]) @ m)
    x = RNG.standard_normal(sum(states))
    slot = np.r_[np.arange(8, 12), np.arange(12 + 4, 12 + 10)]  # each law's newest command in flight: 2 per loop
    turn = lambda: np.exp(1j * RNG.uniform(0, 2 * np.pi, index.size))  # noqa: E731
    now, ahead, sent_ahead = turn(), turn(), turn()
    command_sent = _complex(loops) if sent else np.zeros(0, complex)
    error, integral = _complex(loops), _complex(index.size)
    limit = RNG.uniform(0.5, 3.0, loops)
    limit[index[0]], limit[index[1]], limit[index[2]] = 0.0, 0.05, np.nan  # resting, over its limit, none told
    expected = _numpy_cluster_period(cka, kam, ki, x, slot, command_sent, now, ahead, sent_ahead, error, limit,
                                     index, integral)
    laws = tuple((mat.data, mat.indices, mat.indptr) for mat in (cka, kam, ki))
    innovation, command = np.zeros(index.size, complex), np.zeros(loops, complex)
    scratch = np.empty(cka.shape[0]), np.empty(kam.shape[0])
    kernels.cluster_period(laws, (x, slot, command_sent), (now, ahead, sent_ahead), (error, limit, index),
                           (integral, innovation), scratch, command)
    out, state, held, told = expected
    assert np.allclose(command[index], out, rtol=1e-13) and not np.any(np.delete(command, index))
    assert np.allclose(x, state, rtol=1e-13) and np.allclose(integral, held, rtol=1e-13)
    assert np.allclose(innovation, told, rtol=1e-13)
    assert command[index[0]] == 0 and abs(abs(command[index[1]]) - 0.05) < 1e-12  # the branches taken


class _PythonLiftDetector:
    """LiftDetector's test as plain Python evaluated it, before it was compiled."""

    def __init__(self, keep, arm, observed, drop_min, clip):
        self.keep, self.arm, self.observed, self.drop_min, self.clip = keep, arm, observed, drop_min, clip
        self.reset()

    def reset(self):
        self.mean = self.var = self.weight = 0.0
        self.seen, self.normal = 0, -1

    def update(self, period, short, long):
        if not (long > 0 and np.isfinite(short)):
            self.reset()
            return None
        s = 1 - short / long
        spread = np.sqrt(self.var)
        if self.seen >= self.arm and s > self.drop_min and s > self.mean + self.observed * spread:
            since = self.normal + 1 if self.normal >= 0 else period
            self.reset()
            return since
        if s <= self.mean + spread or self.seen < self.arm:
            self.normal = period
        self.seen += 1
        if self.seen > self.arm:
            s = min(s, self.mean + self.clip * spread)
        self.weight = self.keep * self.weight + 1
        step = (s - self.mean) / self.weight
        self.var = (1 - 1 / self.weight) * (self.var + step * (s - self.mean))
        self.mean += step
        return None


def test_lift_statistics_tell_the_lifts_python_told():
    """A damping steady with noise, unread now and then (nan), then falling: the same lifts told, dated alike, and
    the same statistics every period."""
    keep, arm, limits = np.exp(-1 / 80), 80.0, (6.0, 0.05, 2.0)
    python, stats, told = _PythonLiftDetector(keep, arm, *limits), np.array([0.0, 0.0, 0.0, 0.0, -1.0]), []
    for period in range(900):
        long = 1.0 + 0.02 * RNG.standard_normal()
        short = long * (1 + 0.03 * RNG.standard_normal()) * (0.3 if period % 400 > 320 else 1.0)
        if period in (430, 440):  # not read: the statistics start again
            short = np.nan
        expected = python.update(period, short, long)
        since = kernels.lift_statistics(stats, period, short, long, keep, arm, limits)
        assert (None if since < 0 else since) == expected
        assert np.allclose(stats, [python.mean, python.var, python.weight, python.seen, python.normal], rtol=1e-12)
        told += [since] if since >= 0 else []
    assert len(told) >= 2  # lifts were told
