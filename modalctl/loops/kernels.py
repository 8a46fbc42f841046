"""The loops' per-period arithmetic, compiled (numba): what a loop update does on every mode, each
period, at 20 kHz.

Each step below was a dozen to twenty numpy calls on arrays of a few tens of modes, and a numpy
call costs 1-2 us whatever its size: the touch controller's update on panel-rounded took 180 us
(``benchmarks/plate_speed.py``), where a period at 20 kHz lasts 50. Compiled, a step is one call
over plain loops, and the update takes 67-75 us in the shot, 48-49 us replayed (2026-11-30,
``benchmarks/loop_update.py``; the rest is the controllers' Python around the kernels). The arrays are the
callers' own, updated in place; the laws are documented where they are used (:mod:`.pi`, :mod:`.design`,
:mod:`.touch_estimator`, :mod:`.envelope_noise`, :mod:`.touch_lift`, :mod:`.catch_up`, :mod:`.overlap`,
:mod:`.cluster`, :mod:`.supervisor`, :mod:`.runtime`), and each is tested against the numpy (or the Python)
it replaced (``tests/test_kernels.py``).

Each is compiled when first called, numba imported then (an open-loop shot never pays for it), and
cached beside this file (numba's ``cache=True``; in numba's user-wide cache when the folder is
read-only): a process loads them in 0.4 s (numba's import 0.13 s, its first kernel 0.25 s, each next
3 ms: :func:`warm`, which a closed-loop run starts while its plan waits on DAQP), a machine compiles them once (a
few seconds). Call them as attributes of this module (``kernels.pi_update(...)``): the first call puts
the compiled kernel in the stub's place.
"""

from __future__ import annotations

import threading

import numpy as np

from modalctl.threads import IdleWork

KERNELS: list = []  # every kernel's name, as defined below
_HELPERS: list = []  # the plain functions kernels call, compiled before the first kernel is
_COMPILING = threading.Lock()


class _Kernel:
    """A stub for ``source``, compiled (numba ``njit``) at its first call, which it hands on; the compiled
    kernel then stands in the module in the stub's place (the helpers it calls compiled first)."""

    def __init__(self, source):
        self.source = source
        KERNELS.append(source.__name__)

    def __call__(self, *args):
        import numba

        with _COMPILING:  # warm_soon's thread and the caller's may both get here first
            while _HELPERS:
                name = _HELPERS.pop()
                globals()[name] = numba.njit(cache=True, nogil=True)(globals()[name])
        kernel = numba.njit(cache=True, nogil=True)(self.source)
        globals()[self.source.__name__] = kernel
        return kernel(*args)


def _helper(function):
    """A function kernels call: compiled (and in their place) before the first kernel is."""
    _HELPERS.append(function.__name__)
    return function


@_helper
def _filtered(step, io, i, nxt):
    """Mode ``i``'s filter one sample on (``step``, ``io``: as :func:`filter_step`'s, its input in ``io[i, 0]``):
    its output, the next state written in ``io[i, 1:]`` (``nxt``: scratch, (o + 1,))."""
    n = io.shape[1]
    for r in range(n):
        acc = 0j
        for c in range(n):
            acc += step[i, r, c] * io[i, c]
        nxt[r] = acc
    for r in range(1, n):
        io[i, r] = nxt[r]
    return nxt[0]


@_helper
def _place_terms(sums, q, m):
    """The touch estimator's fit at a place of pattern ``q`` (k,) on memory ``m`` of its ``sums``:
    ``sum_k q_k Re(h_k* e_k)`` and ``sum_k q_k^2 |h_k|^2``."""
    num = den = 0.0
    for i in range(q.size):
        num += q[i] * sums[m, 0, 1, i]
        den += q[i] * q[i] * sums[m, 1, 1, i]
    return num, den


@_Kernel
def pi_update(kp, ki_period, integral, error, limit, command):
    """The PI law (:class:`~modalctl.loops.pi.PIControl`) on each mode: ``command`` (k,) complex written,
    ``integral`` (k,) moved on. A loop whose limit is not positive (or not a number) rests, its integral
    emptied; one over its limit and pushing further holds its integral (anti-windup), then is brought
    to its limit."""
    for k in range(error.size):
        cap = limit[k]
        if not cap > 0:
            integral[k] = 0j
            command[k] = 0j
            continue
        e = error[k]
        proportional = kp[k] * e
        trial = integral[k] + ki_period[k] * e
        c = proportional + trial
        size = abs(c)
        if size > cap:
            if (c.conjugate() * e).real > 0:
                trial = integral[k]
                c = proportional + trial
                size = abs(c)
            if size > cap:
                c = c * (cap / size)
        integral[k] = trial
        command[k] = c


@_Kernel
def filter_step(step, io, out):
    """One sample of each mode's filter in state space (:class:`~modalctl.loops.design.CommandFilter`):
    ``io`` (k, o + 1) complex holds each mode's input then its state; ``step`` (k, o + 1, o + 1) real,
    ``[[D, C], [B, A]]``. Writes the outputs in ``out`` (k,) and the next states in ``io``."""
    nxt = np.empty(io.shape[1], np.complex128)
    for i in range(io.shape[0]):
        out[i] = _filtered(step, io, i, nxt)


@_Kernel
def regression_step(weights, inputs, first, new, eh, sums, keep):
    """One period of the touch estimator's forgotten sums (:meth:`TouchEstimator.update
    <modalctl.loops.touch_estimator.TouchEstimator.update>`): this period's envelope, drive and expected
    residual ``new`` (three (k,)) written in ``inputs`` (5, k + 1) rows ``first``, ``first + 1`` and 4;
    then ``eh[r] = sum_j weights[r, j] inputs[j]`` per mode ((3, k + 1): e, h, -j e), and per memory
    ``m`` ``sums[m] = keep[m] sums[m] + P``, with ``P[i, j] = Re(conj(eh[i]) eh[j])`` for i in (e, h),
    j in (e, h, -j e), shape (m, 2, 3, k + 1)."""
    envelope, drive, expected = new
    for i in range(envelope.size):
        inputs[first, i], inputs[first + 1, i], inputs[4, i] = envelope[i], drive[i], expected[i]
    rows, terms, k = weights.shape
    for r in range(rows):
        for i in range(k):
            acc = 0j
            for j in range(terms):
                acc += weights[r, j, i] * inputs[j, i]
            eh[r, i] = acc
    products = np.empty((2, 3))
    for i in range(k):
        for a in range(2):
            x = eh[a, i]
            for b in range(3):
                y = eh[b, i]
                products[a, b] = x.real * y.real + x.imag * y.imag
        for m in range(keep.size):
            w = keep[m]
            for a in range(2):
                for b in range(3):
                    sums[m, a, b, i] = sums[m, a, b, i] * w + products[a, b]


@_Kernel
def noise_carry(turn, stationary, lam2, rho_lam, last, h, carried, crossed):
    """One period of :class:`~modalctl.loops.envelope_noise.NoiseSums`' sums A (``carried``) and B
    (``crossed``), (m, k) each, from last period's regressor ``last`` and this one's ``h`` (k,):
    ``d = last - turn h``, ``A <- lam^2 (A + Re(d* (2 B + C d)))``, ``B <- rho lam (B + C d)``; then
    ``h`` copied into ``last`` for the next."""
    m, k = turn.shape
    for i in range(k):
        for j in range(m):
            d = last[i] - turn[j, i] * h[i]
            w = stationary[i] * d + crossed[j, i]
            twice = w + crossed[j, i]
            carried[j, i] = (carried[j, i] + d.real * twice.real + d.imag * twice.imag) * lam2[j, 0]
            crossed[j, i] = rho_lam[j, i] * w
        last[i] = h[i]


@_Kernel
def catch_up_period(motion, lockin, loops, plan, scale, out):
    """One period of :class:`~modalctl.loops.catch_up.CatchUp` on its k modes, in place:

    - ``motion`` = (``model`` (3, k): each envelope's pole over a period ``a`` and its answers ``r0``, ``r1`` to
      the last and the playing correction; ``state``, ``last``, ``playing`` (k,)): ``state <- a state + r0 last
      + r1 playing``, what the corrections have added to each envelope;
    - ``lockin`` = (``step`` (k, o + 1, o + 1), ``io`` (k, o + 1)): the state through the lock-in's filter
      (as :func:`filter_step`), what the readings will still show of it;
    - ``loops`` = (``error``, ``limit`` (K,) of every loop, ``modes`` (k,) its among them, ``feedback`` (K,)):
      the deficit ``lost = error - state + filtered``, its share of the plan ``max(Re(lost plan[0]), 0)`` times
      ``plan[1] * scale`` on the loops with authority (``limit > 0``) is the force ``out`` (k,), added to
      ``feedback``; ``scale`` 0 (the focus passed): no force."""
    model, state, last, playing = motion
    step, io = lockin
    error, limit, modes, feedback = loops
    nxt = np.empty(io.shape[1], np.complex128)
    for i in range(state.size):
        s = model[0, i] * state[i] + model[1, i] * last[i] + model[2, i] * playing[i]
        state[i] = s
        io[i, 0] = s
        filtered = _filtered(step, io, i, nxt)
        k = modes[i]
        along = ((error[k] - s + filtered) * plan[0, i]).real
        if scale > 0 and along > 0 and limit[k] > 0:
            out[i] = plan[1, i] * along * scale
            feedback[k] += out[i]
        else:
            out[i] = 0j


@_Kernel
def overlap_commands(forces, base, index, turn, inverse, out):
    """``base`` plus the commands that make ``forces`` (k,) on modes whose resonances overlap
    (:class:`~modalctl.loops.overlap.Overlapping`): ``out = base + forces`` (k,), but on the modes ``index``
    (g,) ``out[index] = base[index] + conj(turn) * (inverse @ (turn * forces[index]))`` (``turn`` (g,),
    ``inverse`` (g, g))."""
    for i in range(forces.size):
        out[i] = base[i] + forces[i]
    g = index.size
    turned = np.empty(g, np.complex128)
    for i in range(g):
        turned[i] = turn[i] * forces[index[i]]
    for r in range(g):
        acc = 0j
        for c in range(g):
            acc += inverse[r, c] * turned[c]
        out[index[r]] = base[index[r]] + turn[r].conjugate() * acc


@_Kernel
def loop_errors(reference, measured, leak, command, own_plan, error, own):
    """A period's errors (:meth:`Runtime.update <modalctl.loops.runtime.Runtime.update>`), (k,) each:
    ``error = reference - measured + leak command`` and each mode's own answer ``own = own_plan - error``
    (the measured less what its reading holds of the others' and the leak)."""
    for i in range(error.size):
        e = reference[i] - measured[i] + leak[i] * command[i]
        error[i] = e
        own[i] = own_plan[i] - e


@_helper
def _csr(data, indices, indptr, x, out):
    """``out = M @ x`` for ``M`` in compressed sparse rows (``data``, ``indices``, ``indptr``: scipy's CSR
    arrays), ``x`` (n,) real: the cluster laws' block-diagonal products (:func:`cluster_period`), where
    scipy's own spent ~10 us a call on checks."""
    for r in range(indptr.size - 1):
        acc = 0.0
        for j in range(np.uint64(indptr[r]), np.uint64(indptr[r + 1])):  # unsigned: no check for a negative
            acc += data[j] * x[np.uint64(indices[j])]  # index's wrap-around in the loop (CKA's 14,580: 26 -> 12 us)
        out[r] = acc


@_Kernel
def cluster_period(laws, state, turns, loops, memory, scratch, command):
    """One period of the cluster laws stacked (:meth:`ClusterControl.update
    <modalctl.loops.cluster.ClusterControl.update>`, whose notes give the law), in place, on their g loops:

    - ``laws`` = ``[C; K; A]``, ``[K; A] M`` and ``Ki``, each as CSR ``(data, indices, indptr)``;
    - ``state`` = (``x`` (S,): the stacked predicted state (real I/Q), moved on to the next period's; ``slot``
      (2 g,): where the newest command in flight sits in it; ``sent`` (K,): every loop's command last sent, size 0
      when none was);
    - ``turns`` = (``now``, ``ahead``, ``sent_ahead``) (g,): the frames' turn at this reading, and its factors to
      when the command computed now and the one last sent are reached;
    - ``loops`` = (``error``, ``limit`` (K,) of every loop, ``index`` (g,) the laws' loops among them);
    - ``memory`` = (``integral`` (g,), moved on by :func:`_limited`'s law, ``innovation`` (g,), written);
    - ``scratch``: two float arrays, the rows of the first two laws; the commands written in ``command[index]``.

    One call where the update was three sparse products and a dozen numpy calls around them: the default
    controller's update on panel-rounded (19 laws, 654 states) 125-127 -> 103-104 us replayed (2026-11-30,
    three alternated pairs), in the shot thesis-al-cc's 101 -> 79 us, plate-glass's 134 -> 109 us; the same
    shots to the last digit."""
    (cka, ckai, ckap), (kam, kami, kamp), (ki, kii, kip) = laws
    x, slot, sent = state
    error, limit, index = loops
    integral, innovation = memory
    now, ahead, sent_ahead = turns
    predicted, joined = scratch
    g = index.size
    if sent.size:
        for i in range(g):
            v = sent[index[i]] * now[i] * sent_ahead[i]
            x[slot[2 * i]], x[slot[2 * i + 1]] = v.real, v.imag
    _csr(cka, ckai, ckap, x, predicted)  # C x, K x, A x of the prediction
    surprise = np.empty(2 * g)
    z = np.empty(g, np.complex128)
    for i in range(g):
        z[i] = -error[index[i]]  # the measured deviation from the plan, in each loop's frame
        v = z[i] * now[i]
        surprise[2 * i], surprise[2 * i + 1] = v.real - predicted[2 * i], v.imag - predicted[2 * i + 1]
        innovation[i] = complex(surprise[2 * i], surprise[2 * i + 1]) / now[i]
    _csr(kam, kami, kamp, surprise, joined)  # [K; A] M surprise
    for r in range(joined.size):
        joined[r] += predicted[2 * g + r]  # K x, A x of the corrected state
    turned = np.empty(2 * g)
    for i in range(g):
        v = integral[i] * now[i]
        turned[2 * i], turned[2 * i + 1] = v.real, v.imag
    integrated = np.empty(2 * g)
    _csr(ki, kii, kip, turned, integrated)
    out = np.empty(g, np.complex128)
    for i in range(g):
        out[i] = complex(-joined[2 * i] - integrated[2 * i], -joined[2 * i + 1] - integrated[2 * i + 1]) \
            / (now[i] * ahead[i])
    _limited(out, limit, index, integral, z)  # authority, anti-windup
    for r in range(x.size):
        x[r] = joined[2 * g + r]  # the next period's prediction
    for i in range(g):
        v = out[i] * (now[i] * ahead[i])  # B: the command enters the delay line's first slot
        x[slot[2 * i]] += v.real
        x[slot[2 * i + 1]] += v.imag
        command[index[i]] = out[i]


@_helper
def _limited(out, limit, index, integral, z):
    """The cluster laws' authority, per loop ``i`` of theirs (``index[i]`` among all the loops' ``limit``): a
    command ``out[i]`` over its limit is brought to it and its integral held (anti-windup), else the integral
    takes ``z[i]``; a loop whose limit is not above zero rests its integral."""
    for i in range(out.size):
        cap = limit[index[i]]
        size = abs(out[i])
        if size > cap:
            out[i] = out[i] * (cap / max(size, 1e-300))
        else:
            integral[i] += z[i]
        if cap <= 0:
            integral[i] = 0j


@_Kernel
def over_any(values, bound):
    """Whether any ``|values[i]|`` (k,) exceeds ``bound[i]``."""
    for i in range(values.size):
        if abs(values[i]) > bound[i]:
            return True
    return False


@_Kernel
def quick_bound_within(quick, size_old, new, room, size_new):
    """The supervisor's quick bound (:meth:`~modalctl.loops.supervisor.Supervisor.limit`): ``size_new =
    |new|`` (k,) written, and whether ``quick @ max(size_old, size_new)`` ((2 a, k) @ (k,)) is within
    ``room`` (2 a,) on every channel."""
    for i in range(new.size):
        size_new[i] = abs(new[i])
    within = True
    for r in range(quick.shape[0]):
        acc = 0.0
        for i in range(new.size):
            acc += quick[r, i] * max(size_old[i], size_new[i])
        if acc > room[r]:
            within = False
    return within


@_Kernel
def place_sums(sums, q, reads, out):
    """The touch estimator's sums at a place of pattern ``q`` (k,) (:meth:`TouchEstimator._at
    <modalctl.loops.touch_estimator.TouchEstimator._at>`), per memory m of ``sums`` (m, 2, 3, k + 1):
    ``sum_k q_k Re(h_k* e_k)``, ``sum_k q_k^2 |h_k|^2``, ``sum_k |e_k|^2`` and the weighted count of
    complex residuals (the last column's ``|e|^2`` times ``reads``), written in ``out`` (4, m)."""
    k = q.size
    for m in range(sums.shape[0]):
        num, den = _place_terms(sums, q, m)
        energy = 0.0
        for i in range(k):
            energy += sums[m, 0, 0, i]
        out[0, m], out[1, m], out[2, m], out[3, m] = num, den, energy, sums[m, 0, 0, k] * reads


@_Kernel
def place_dampings(sums, q):
    """The damping at a place of pattern ``q`` (k,) on the shortest and the longest memory of the touch
    estimator's ``sums`` (:meth:`TouchEstimator.dampings <modalctl.loops.touch_estimator.TouchEstimator.dampings>`):
    ``-sum_k q_k Re(h_k* e_k) / sum_k q_k^2 |h_k|^2`` on each, nan where the denominator is not positive."""
    found = np.empty(2)
    for slot, m in enumerate((0, sums.shape[0] - 1)):
        num, den = _place_terms(sums, q, m)
        found[slot] = -num / den if den > 0 else np.nan
    return found[0], found[1]


@_Kernel
def lift_statistics(stats, period, short, long, keep, arm, limits):
    """One period of :class:`~modalctl.loops.touch_lift.LiftDetector`: ``stats`` (5,) = the observed mean and
    variance of ``s = 1 - short / long``, their weight, the periods seen and the last period ``s`` lay within
    one deviation of its mean, moved on in place; ``limits`` = (OBSERVED, DROP_MIN, CLIP). Returns the period a
    lift is dated to when one is told now (``stats`` then reset), else -1; a damping not read resets them."""
    observed, drop_min, clip = limits
    if not (long > 0 and np.isfinite(short)):
        stats[:] = 0.0
        stats[4] = -1.0
        return -1
    mean, var, weight, seen, normal = stats[0], stats[1], stats[2], stats[3], stats[4]
    s = 1 - short / long
    spread = np.sqrt(var)
    if seen >= arm and s > drop_min and s > mean + observed * spread:
        stats[:] = 0.0
        stats[4] = -1.0
        return int(normal) + 1 if normal >= 0 else period
    if s <= mean + spread or seen < arm:
        normal = period
    seen += 1
    if seen > arm:  # a change coming in must not widen the spread it is told against (Huber's clip)
        s = min(s, mean + clip * spread)
    weight = keep * weight + 1
    step = (s - mean) / weight  # exponentially weighted mean and variance (West 1979)
    var = (1 - 1 / weight) * (var + step * (s - mean))
    stats[0], stats[1], stats[2], stats[3], stats[4] = mean + step, var, weight, seen, normal
    return -1


_warming: list = []  # the work warm_soon started, while it runs


def warm_soon(idle: bool = True) -> None:
    """:func:`warm` in a daemon thread: numba's import and then the kernels, each begun while the caller waits
    on a call that lets go of the interpreter (``idle``: a convex plan's DAQP solves,
    :class:`modalctl.threads.IdleWork`), or at once; :func:`warm` then waits for it, :func:`cancel_warm` stops
    what has not begun (a plan refused: nothing loads behind the caller's back after)."""
    _warming.append(IdleWork([_import_numba, _load], "modalctl-kernels", idle=idle))


def cancel_warm() -> None:
    """No kernel :func:`warm_soon` began loading begins from now on."""
    while _warming:
        _warming.pop().cancel()


def warm() -> None:
    """Load (or compile, the first time on a machine) every kernel on arrays of the types the loops pass,
    so that a shot's first periods do not pay for it; when :func:`warm_soon` is loading them, wait for it."""
    while _warming:
        _warming.pop().finish()
    _load()


def _import_numba() -> None:
    import numba  # noqa: F401 - its import, 0.13 s, a step of its own


def _load() -> None:
    """Every kernel called once on arrays of the types and layouts the loops pass (numba compiles one
    version per type signature)."""
    c, r, r2 = np.zeros(1, complex), np.zeros(1), np.zeros((1, 1))
    kernel = globals()
    kernel["pi_update"](r, r, c.copy(), c, r, c.copy())
    kernel["filter_step"](np.zeros((1, 2, 2)), np.zeros((1, 2), complex), c.copy())
    kernel["regression_step"](np.zeros((3, 5, 2), complex), np.zeros((5, 2), complex), 0, (c, c, c),
                              np.zeros((3, 2), complex), np.zeros((1, 2, 3, 2)), r)
    kernel["noise_carry"](np.zeros((1, 1), complex), r, r2, r2, c, c, r2.copy(), np.zeros((1, 1), complex))
    kernel["catch_up_period"]((np.zeros((3, 1), complex), c.copy(), c, c),
                              (np.zeros((1, 2, 2)), np.zeros((1, 2), complex)), (c, r, np.zeros(1, np.int64), c.copy()),
                              np.zeros((2, 1), complex), 1.0, c.copy())
    kernel["overlap_commands"](c, c, np.zeros(1, np.int64), c, np.zeros((1, 1), complex), c.copy())
    kernel["loop_errors"](c, c, c, c, c, c.copy(), c.copy())
    csr = (np.zeros(1), np.zeros(1, np.int64), np.array([0, 1], np.int64))
    one = np.ones(1, complex)  # a turn
    kernel["cluster_period"]((csr, csr, csr), (np.zeros(2), np.arange(2), c), (one, one, one),
                             (c, r, np.zeros(1, np.int64)), (c.copy(), c.copy()), (np.zeros(6), np.zeros(4)),
                             c.copy())  # one loop, two states
    kernel["over_any"](c, r)
    kernel["quick_bound_within"](r2, r, c, r, r.copy())
    kernel["place_sums"](np.zeros((1, 2, 3, 2)), r, 1.0, np.zeros((4, 1)))
    kernel["place_dampings"](np.zeros((1, 2, 3, 2)), r)
    kernel["lift_statistics"](np.zeros(5), 0, 1.0, 1.0, 0.5, 1.0, (6.0, 0.05, 2.0))


__all__ = [*KERNELS, "warm", "warm_soon", "cancel_warm"]
