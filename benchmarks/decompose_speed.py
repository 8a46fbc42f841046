"""Decomposition throughput: shapes per second for 21 modes on a 1,000-point beam grid and a
100 x 70 plate grid, against numpy's least-squares fit (the peer a user would write) in the same run.

    python benchmarks/decompose_speed.py   # writes benchmarks/results/decompose_speed.json

Each case: generate the target field (sinc), project on the modes, reconstruct, compute tau.
Medians over repeats; ratios are measured in this run on this machine.
"""

from __future__ import annotations

import numpy as np
from common import command_line, median_seconds, write_json

from modalctl.model.metrics import tau
from modalctl.model.projection import project, reconstruct
from modalctl.model.shape import parse_params
from modalctl.model.structures import Beam, Plate
from modalctl.plugin.manager import get_shape

REPEATS, BATCH = 31, 256


def case(name: str, model, center: str) -> dict:
    generator = get_shape("sinc")
    params = parse_params(generator, {"width": "15mm", "center": center})
    shapes, mass = model.shapes, model.grid.mass
    root_shapes_t = (shapes * np.sqrt(mass)).T
    fields = np.array([generator.generate(model.grid, **params).values for _ in range(BATCH)])

    def one_shape():
        field = generator.generate(model.grid, **params).values
        c = project(field, shapes, mass)
        return tau(field, reconstruct(c, shapes))

    def projection_only():
        return project(fields[0], shapes, mass)

    def batch():
        c = project(fields, shapes, mass)
        return tau(fields, reconstruct(c, shapes))

    def peer_lstsq():
        c, *_ = np.linalg.lstsq(root_shapes_t, fields[0] * np.sqrt(mass), rcond=None)
        return c

    t_one, t_proj = median_seconds(one_shape, REPEATS), median_seconds(projection_only, REPEATS)
    t_batch, t_peer = median_seconds(batch, 11), median_seconds(peer_lstsq, REPEATS)
    return {
        "case": name, "modes": int(model.n_modes), "points": int(model.grid.n),
        "shapes_per_s_end_to_end": 1 / t_one,
        "shapes_per_s_batched": BATCH / t_batch,
        "projection_median_s": t_proj,
        "peer_lstsq_median_s": t_peer,
        "speedup_projection_vs_lstsq": t_peer / t_proj,
    }


def main() -> dict:
    beam = Beam(0.105, 0.007, 0.001, 69e9, 2700, "clamped-clamped").modal_model(21, n_points=1000)
    plate = Plate(0.1, 0.07, 0.001, 70e9, 2500).modal_model(21, nx=100, ny=70)
    report = {"statistic": "median", "repeats": REPEATS, "batch": BATCH,
              "cases": [case("beam 1000 points", beam, "24mm"), case("plate 100x70", plate, "20mm,10mm")]}
    write_json("decompose_speed", report)
    return report


if __name__ == "__main__":
    command_line()
    for c in main()["cases"]:
        print(f"{c['case']:18s} {c['shapes_per_s_end_to_end']:9.0f} shapes/s end to end, "
              f"{c['shapes_per_s_batched']:9.0f} batched; projection {1e6 * c['projection_median_s']:.1f} us, "
              f"{c['speedup_projection_vs_lstsq']:.1f}x faster than lstsq")
