"""Measured FRFs from universal files (UFF 58), read as labs export them.

What the file says is what is read: the function type (only FRFs), the response (displacement,
velocity, acceleration: converted to mobility), the directions (negative ones turned), the
input's unit (force in N, or a voltage), and the layout of the test:

- one reference, many responses (a shaker, or a roving accelerometer): the responses are the
  points, the reference the actuator;
- many references, fewer responses (a roving hammer, with one accelerometer or a few): read by
  reciprocity (``H_pq = H_qp``), the hammer points are the points and each accelerometer an input;
- a few references and more responses (a multi-reference test): one FRF per reference, every
  one on the same response points.

Coherences (function type 6) exported beside the FRFs are read with them (``FRF.coherence``).
Bins where a conversion is singular (the 0 Hz bin of an accelerance divided by ``j w``) are
dropped and said so; every conversion is said in ``FRF.notes``.
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np

from modalctl.model.modes import ModelError

from .frf import FRF

__all__ = ["read_uff58", "read_uff58_references", "FUNCTION_TYPES", "RESPONSES", "UFF_POINTS_MAX", "UFF_BINS_MAX",
           "FRF_MAX"]

# UFF 58, record 6 field 1: what a function is (only FRFs are identified from)
FUNCTION_TYPES = {0: "a general or unknown function", 1: "time response data", 2: "an auto-spectrum",
                  3: "a cross-spectrum", 4: "a frequency response function", 5: "a transmissibility",
                  6: "a coherence", 7: "an auto-correlation", 8: "a cross-correlation",
                  9: "a power spectral density", 10: "an energy spectral density",
                  11: "a probability density function", 12: "a spectrum",
                  13: "a cumulative frequency distribution", 14: "peaks and valleys", 15: "stress per cycle",
                  16: "strain per cycle", 17: "an orbit", 18: "a mode indicator function", 19: "a force pattern",
                  20: "a partial power", 21: "a partial coherence", 22: "eigenvalues", 23: "eigenvectors",
                  24: "a shock response spectrum", 25: "a finite impulse response filter",
                  26: "a multiple coherence", 27: "an order function"}
# record 9 field 1 (the ordinate's numerator): the power of j w that turns it into a mobility
RESPONSES = {8: ("receptance", 1), 11: ("mobility", 0), 12: ("accelerance", -1)}
FORCES = {9, 13}  # record 10 field 1 (the denominator): a reaction or an excitation force (N)
FREQUENCY = 18  # record 8 field 1: the abscissa is a frequency (Hz)
FRF_TYPE, COHERENCE = 4, 6  # record 6 field 1: the functions read (a coherence beside its FRF)
NODE_SETS = (15, 2411)  # datasets that give node coordinates
UFF_POINTS_MAX = 100_000  # functions one file may hold
UFF_BINS_MAX = 1 << 21  # bins per FRF
FRF_MAX = 1e100  # an FRF's magnitude at most, in any unit: a sensor's counts per newton are below 1e12


def _refuse(path, what: str) -> ModelError:
    return ModelError(f"uff: {str(path)!r}: {what}")


def _frf_sets(path, sets: list[dict]) -> tuple[list[dict], list[dict]]:
    """The FRFs and the coherences among the datasets 58 of a file, refused unless every one is
    one of those two against frequency and there is an FRF."""
    functions = [s for s in sets if s.get("type") == 58]
    if not functions:
        raise _refuse(path, "no dataset 58 (functions at nodes)")
    if len(functions) > UFF_POINTS_MAX:
        raise _refuse(path, f"{len(functions)} functions; at most {UFF_POINTS_MAX}")
    kinds = sorted({int(s.get("func_type", 0)) for s in functions})
    if FRF_TYPE not in kinds or set(kinds) - {FRF_TYPE, COHERENCE}:
        held = ", ".join(f"{FUNCTION_TYPES.get(k, 'an unknown function')} (function type {k})" for k in kinds)
        raise _refuse(path, f"holds {held}; modes are identified from frequency response functions "
                            f"(function type 4), with their coherences (6) if exported")
    axes = sorted({int(s.get("abscissa_spec_data_type", FREQUENCY)) for s in functions})
    if axes != [FREQUENCY]:
        raise _refuse(path, f"abscissa of data type(s) {axes}; FRFs against frequency (18) are expected")
    return ([s for s in functions if int(s.get("func_type", 0)) == FRF_TYPE],
            [s for s in functions if int(s.get("func_type", 0)) == COHERENCE])


def _channel(s: dict) -> tuple:
    """What a function is measured between: response node and direction, reference node and direction."""
    return tuple(int(s.get(k, 0)) for k in ("rsp_node", "rsp_dir", "ref_node", "ref_dir"))


def _coherence(path, frfs: list[dict], coherences: list[dict], freqs: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """Each FRF's coherence (rows in file order), ones when the file has none; every FRF needs its
    own, on its frequencies, real, finite and within [0, 1] (rounding above 1 clipped)."""
    if not coherences:
        return np.ones((len(frfs), freqs.size)), []
    by_channel = {_channel(s): s for s in coherences}
    rows = []
    for s in frfs:
        c = by_channel.get(_channel(s))
        if c is None:
            raise _refuse(path, f"the FRF of response node {s['rsp_node']} to reference node {s['ref_node']} has no "
                                f"coherence, which others have; export all or none")
        values = np.asarray(c["data"])
        if not np.array_equal(np.asarray(c["x"], float), freqs) or np.iscomplexobj(values) and np.any(values.imag):
            raise _refuse(path, f"the coherence of response node {s['rsp_node']} is not real on the FRFs' frequencies")
        values = np.real(values).astype(float)
        if not np.all(np.isfinite(values)) or values.min() < 0 or values.max() > 1 + 1e-6:
            raise _refuse(path, f"the coherence of response node {s['rsp_node']} leaves [0, 1]")
        rows.append(np.minimum(values, 1.0))
    coherence = np.array(rows)
    return coherence, [f"coherence read with each FRF (function type 6): median {np.median(coherence):.2f}, lowest "
                       f"{coherence.min():.2f}; with no number of averages in the file it gives the noise's shape, "
                       f"the scatter between lines its level"]


def input_unit(frfs: list[dict]) -> str:
    """The unit of the FRFs' input: ``"N"`` for a force (data type 9 or 13, or a label in N),
    ``"V"`` for a voltage (a label in V), else ``"unit input"`` (the file does not say)."""
    kinds = {int(s.get("orddenom_spec_data_type", 0)) for s in frfs}
    labels = {str(s.get("orddenom_axis_units_lab", "")).strip().lower() for s in frfs}
    if kinds and kinds <= FORCES or labels & {"n", "newton"}:
        return "N"
    if labels & {"v", "volt", "volts"}:
        return "V"
    return "unit input"


def _mobility(path, frfs: list[dict], freqs: np.ndarray, point_dir: str) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Every FRF as a mobility (m/s per unit input) along +axis, rows in file order; the bins
    kept (those where the conversion is finite) and the notes. ``point_dir``: the key of the
    points' directions (``rsp_dir``, or ``ref_dir`` for a roving hammer read by reciprocity): the
    points must share one axis (a shape is one component of the motion); the inputs may not."""
    kinds = sorted({int(s.get("ordinate_spec_data_type", 11)) for s in frfs})
    unknown = [k for k in kinds if k not in RESPONSES]
    if unknown or len(kinds) != 1:
        what = "mixed responses" if len(kinds) > 1 else f"a response of data type {unknown[0]}"
        raise _refuse(path, f"{what}; FRFs of displacement (8), velocity (11) or acceleration (12) "
                            f"are identified, one kind per file")
    name, power = RESPONSES[kinds[0]]
    axes = {abs(int(s.get(k, 3))) for s in frfs for k in ("rsp_dir", "ref_dir")} - {0}
    along = sorted({abs(int(s.get(point_dir, 3))) for s in frfs} - {0})
    if len(along) > 1 or axes - {1, 2, 3}:
        points = "responses" if point_dir == "rsp_dir" else "references (the points, read by reciprocity)"
        raise _refuse(path, f"{points} along directions {along}, every direction {sorted(axes)}; the points along "
                            f"one translational axis (1-3, signed) are expected, the inputs along any")
    sign = np.array([np.sign(int(s.get("rsp_dir", 3)) or 1) * np.sign(int(s.get("ref_dir", 3)) or 1)
                     for s in frfs])
    raw = np.array([np.asarray(s["data"], complex) for s in frfs]) * sign[:, None]
    if not np.all(np.isfinite(raw)):
        raise _refuse(path, "an FRF holds NaN or infinite values")
    if np.abs(raw).max(initial=0.0) > FRF_MAX:  # its squares, which the fits sum, overflow (1e300: a singular solve)
        raise _refuse(path, f"an FRF reaches {np.abs(raw).max():.3g}; a measured one stays below {FRF_MAX:g} in any "
                            f"unit")
    with np.errstate(divide="ignore", invalid="ignore"):
        values = raw * (2j * np.pi * freqs) ** power
    keep = np.all(np.isfinite(values), axis=0)
    notes = []
    if power:
        notes.append(f"the file holds {name}s (data type {kinds[0]}): converted to mobility "
                     f"({'times' if power > 0 else 'over'} j w)")
    if not keep.all():
        where = ", ".join(f"{f:g} Hz" for f in freqs[~keep][:3]) + (" ..." if np.count_nonzero(~keep) > 3 else "")
        notes.append(f"{np.count_nonzero(~keep)} bin(s) dropped where the conversion to mobility is singular "
                     f"({where})")
    if np.any(sign < 0):
        notes.append(f"{int(np.sum(sign < 0))} FRF(s) measured along a negative direction: sign turned")
    return values, keep, notes


def _plane_coordinates(path, xyz: np.ndarray) -> np.ndarray:
    """Node coordinates (n, 3) as positions along their line (n, 1) or on their plane (n, 2):
    the axes they vary along when those are two at most and not collinear, else the line's or
    the plane's own axes (a beam along a diagonal, a plate tilted in 3-D)."""
    varying = np.ptp(xyz, axis=0) > 1e-9 * max(float(np.ptp(xyz)), 1e-300)
    if varying.sum() <= 1:
        return xyz[:, varying] if varying.any() else xyz[:, :1]
    centred = xyz - xyz.mean(axis=0)
    _, s, vh = np.linalg.svd(centred, full_matrices=False)
    rank = int(np.count_nonzero(s > 1e-6 * s[0]))
    if rank == 3:
        raise _refuse(path, "the measured nodes do not lie on a line or a plane")
    if rank == 2 and varying.sum() == 2:
        return xyz[:, varying]
    if rank == 1:
        along = vh[0] * np.sign(vh[0][np.argmax(np.abs(vh[0]))])  # its largest component positive
        return (centred @ along)[:, None]
    return centred @ vh[:2].T


def _layout(path, frfs: list[dict]) -> tuple[list[list[int]], list[int], list[str], str]:
    """Which function is which: per input, the indices of its FRFs (one per point, the same
    points in the same order for every input), the point node of each row, a note, and the key of
    the points' directions (``rsp_dir`` or ``ref_dir``).

    More references than responses (a roving hammer, one accelerometer or a few): the references
    are the points (reciprocity), each response an input. Else the responses are the points,
    each reference an input. Every input must have the same points.
    """
    refs = sorted({int(s["ref_node"]) for s in frfs})
    rsps = sorted({int(s["rsp_node"]) for s in frfs})
    swapped = len(refs) > len(rsps)
    point_key, input_key = ("ref_node", "rsp_node") if swapped else ("rsp_node", "ref_node")
    by_input: dict = defaultdict(dict)
    for i, s in enumerate(frfs):
        point = int(s[point_key])
        if point in by_input[int(s[input_key])]:
            what = "reference" if swapped else "response"
            raise _refuse(path, f"{what} node {point} has several FRFs from {'response' if swapped else 'reference'} "
                                f"node {int(s[input_key])}; one per node is expected")
        by_input[int(s[input_key])][point] = i
    inputs = sorted(by_input)
    points = sorted(by_input[inputs[0]])
    for a in inputs[1:]:
        if sorted(by_input[a]) != points:
            missing = sorted(set(points) ^ set(by_input[a]))[:5]
            what = ("responses", "from different reference nodes", "every response from the same references") \
                if swapped else ("references", "at different response nodes", "every reference at the same responses")
            raise _refuse(path, f"{what[0]} {inputs[0]} and {a} were measured {what[1]} (e.g. {missing}); a file of "
                                f"several inputs needs {what[2]}")
    notes = []
    if swapped and len(rsps) == 1:
        notes.append(f"{len(refs)} references and one response (node {rsps[0]}): a roving-hammer test, read by "
                     f"reciprocity (H_pq = H_qp): the hammer points are the points, the response the input")
    elif swapped:
        notes.append(f"{len(refs)} references and {len(rsps)} responses (nodes {rsps[:8]}): a roving-hammer test "
                     f"with {len(rsps)} accelerometers, read by reciprocity (H_pq = H_qp): the hammer points are "
                     f"the points, each response an input")
    elif len(inputs) > 1:
        notes.append(f"{len(inputs)} references (nodes {inputs[:8]}) at the same {len(points)} responses: "
                     f"a multi-reference test, one FRF per reference")
    return [[by_input[a][p] for p in points] for a in inputs], points, notes, point_key.replace("node", "dir")


def _node_table(path, sets: list[dict]) -> tuple[dict, np.ndarray]:
    """Node number -> row, and coordinates (n, 3) in m, from the first dataset 15 or 2411."""
    nodes = [s for s in sets if s.get("type") in NODE_SETS]
    if not nodes:
        raise _refuse(path, "no dataset 15 or 2411 (node coordinates)")
    table = nodes[0]
    xyz = np.column_stack([table["x"], table["y"], table["z"]]).astype(float)
    return {int(n): i for i, n in enumerate(table["node_nums"])}, xyz


def read_uff58_references(path) -> list[FRF]:
    """Measured FRFs from a universal file, one :class:`FRF` per input, read by what the file
    says they are (see the module's description of the layouts).

    Datasets 58 give the functions, dataset 15 (or 2411) the node coordinates (metres assumed);
    needs the optional ``pyuff``. Rows are sorted by position (along a line, or y then x on a
    plane); nodes may be listed in any order, with coordinates on a line, a plane (2-D) or a
    tilted plane in 3-D.

    Returns
    -------
    list of FRF
        One per input (``actuator`` its index), every one on the same points, in mobility
        (m/s per N for a force input, per V for a voltage: ``FRF.input_unit``).
    """
    from modalctl.model.files import read_uff_sets

    sets = read_uff_sets(path)
    frfs, coherences = _frf_sets(path, sets)
    where, xyz = _node_table(path, sets)
    groups, point_nodes, layout_notes, point_dir = _layout(path, frfs)
    missing = [n for n in point_nodes if n not in where]
    if missing:
        raise _refuse(path, f"measured nodes {missing[:5]} have no coordinates in dataset 15")
    freqs = np.asarray(frfs[0]["x"], float)
    if not 8 <= freqs.size <= UFF_BINS_MAX or any(not np.array_equal(np.asarray(s["x"], float), freqs)
                                                  for s in frfs):
        raise _refuse(path, f"the FRFs need one common frequency axis of 8 to {UFF_BINS_MAX} bins")
    step = np.diff(freqs)
    if not np.all(np.isfinite(freqs)) or step.min() <= 0 or np.ptp(step) > 1e-6 * step.mean():
        raise _refuse(path, "the frequencies must be evenly spaced and increasing")
    values, keep, notes = _mobility(path, frfs, freqs, point_dir)
    coherence, coherence_notes = _coherence(path, frfs, coherences, freqs)
    if np.count_nonzero(keep) < 8:
        raise _refuse(path, "fewer than 8 bins left where the conversion to mobility is finite")
    points = _plane_coordinates(path, xyz[[where[n] for n in point_nodes]])
    if len(np.unique(points, axis=0)) != len(points):
        raise _refuse(path, "two measured nodes share coordinates")
    order = np.lexsort(points.T)  # x, then y on a plane
    unit, notes = input_unit(frfs), tuple(layout_notes + notes + coherence_notes)
    result = []
    for a, rows in enumerate(groups):
        rows = np.asarray(rows)[order]
        result.append(FRF(freqs[keep], values[rows][:, keep], coherence[rows][:, keep], points[order], a, 1,
                          notes=notes, input_unit=unit))
    return result


def read_uff58(path) -> FRF:
    """The FRFs of a universal file of one input (one reference, or a roving hammer's many
    references and one response); see :func:`read_uff58_references`, which also reads
    multi-reference files."""
    frfs = read_uff58_references(path)
    if len(frfs) > 1:
        raise _refuse(path, f"{len(frfs)} references at every response; read it with read_uff58_references")
    return frfs[0]
