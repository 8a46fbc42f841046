"""Projection, reconstruction and Gram-Schmidt against independent computations."""

import numpy as np
import pytest

from modalctl.model.modes import ModelError
from modalctl.model.projection import (
    crosstalk,
    gram,
    mass_normalize,
    orthonormalize,
    orthonormalize_model,
    project,
    reconstruct,
)


def test_exact_recovery_of_known_coefficients(al_beam, rng):
    model = al_beam.modal_model(21)
    known = rng.normal(size=21)
    field = known @ model.shapes  # built by hand, not by reconstruct()
    assert project(field, model.shapes, model.grid.mass) == pytest.approx(known, abs=1e-8)
    assert reconstruct(known, model.shapes) == pytest.approx(field, abs=1e-12)


def test_projection_batches_like_single_fields(al_beam, rng):
    model = al_beam.modal_model(10)
    fields = rng.normal(size=(4, model.grid.n))
    batch = project(fields, model.shapes, model.grid.mass)
    singles = np.array([project(f, model.shapes, model.grid.mass) for f in fields])
    assert batch == pytest.approx(singles)


def test_projection_is_the_least_squares_fit_for_orthonormal_modes(al_beam, rng):
    """Independent: the mass-weighted least-squares solution by numpy's lstsq."""
    model = al_beam.modal_model(12)
    field = rng.normal(size=model.grid.n)
    root = np.sqrt(model.grid.mass)
    lstsq, *_ = np.linalg.lstsq((model.shapes * root).T, field * root, rcond=None)
    assert project(field, model.shapes, model.grid.mass) == pytest.approx(lstsq, rel=1e-6, abs=1e-12)


def _skewed(model, rng, amount=0.3):
    """Deliberately mix the modes with a random upper-triangular matrix (what noise and aliasing do)."""
    k = model.n_modes
    mix = np.eye(k) + amount * np.triu(rng.normal(size=(k, k)), 1)
    return mix.T @ model.shapes * rng.uniform(0.5, 2.0, size=(k, 1))


def test_gram_schmidt_restores_identity_crosstalk(al_beam, rng):
    model = al_beam.modal_model(16)
    skewed = _skewed(model, rng)
    before = crosstalk(skewed, model.grid.mass)
    assert np.abs(before - np.eye(16)).max() > 0.1
    ortho, r = orthonormalize(skewed, model.grid.mass)
    assert np.abs(gram(ortho, model.grid.mass) - np.eye(16)).max() < 1e-9
    assert np.abs(crosstalk(ortho, model.grid.mass) - np.eye(16)).max() < 1e-9
    assert r.T @ ortho == pytest.approx(skewed, abs=1e-9 * np.abs(skewed).max())
    assert np.allclose(np.tril(r, -1), 0) and np.all(np.diag(r) > 0)


def test_gram_schmidt_matches_the_classical_recursion(al_beam, rng):
    """Independent: Eqs 3.16-3.18 written out literally on a well-conditioned set."""
    model = al_beam.modal_model(6)
    skewed, mass = _skewed(model, rng, 0.1), model.grid.mass
    classical = []
    for phi in skewed:
        v = phi - sum(((phi * mass) @ q) * q for q in classical)
        classical.append(v / np.sqrt((v * mass) @ v))
    ortho, _ = orthonormalize(skewed, mass)
    assert ortho == pytest.approx(np.array(classical), abs=1e-9 * np.abs(ortho).max())


def test_gram_schmidt_stays_orthogonal_for_nearly_dependent_modes(al_beam, rng):
    """Classical Gram-Schmidt loses orthogonality here; the QR route must not."""
    model = al_beam.modal_model(8)
    near = model.shapes.copy()
    near[1:] = near[0] + 1e-7 * near[1:]  # seven modes almost equal to the first
    ortho, _ = orthonormalize(near, model.grid.mass)
    assert np.abs(gram(ortho, model.grid.mass) - np.eye(8)).max() < 1e-9


def test_dependent_mode_is_reported(al_beam):
    model = al_beam.modal_model(4)
    dependent = np.vstack([model.shapes, model.shapes[0] + model.shapes[2]])
    with pytest.raises(ModelError, match="mode 4 is linearly dependent"):
        orthonormalize(dependent, model.grid.mass)


def test_orthonormalized_model_keeps_the_input_and_output_maps(al_beam, rng):
    base = al_beam.modal_model(10, sensors=[-0.02, 0.03])
    skewed = _skewed(base, rng, 0.2)
    from dataclasses import replace
    model = replace(base, shapes=skewed, actuator_gains=rng.normal(size=(10, 3)), sensor_gains=skewed[:, [100, 700]])
    ortho = orthonormalize_model(model)
    eta = rng.normal(size=10)
    field = eta @ model.shapes
    eta_new = project(field, ortho.shapes, ortho.grid.mass)
    assert eta_new @ ortho.shapes == pytest.approx(field, abs=1e-9 * np.abs(field).max())
    # the field acceleration a voltage produces is the same in either basis
    v = rng.normal(size=3)
    before, after = (model.actuator_gains @ v) @ model.shapes, (ortho.actuator_gains @ v) @ ortho.shapes
    assert after == pytest.approx(before, abs=1e-9 * np.abs(before).max())
    # sensors read the same velocity in either basis
    assert eta_new @ ortho.sensor_gains == pytest.approx(eta @ model.sensor_gains, rel=1e-8)


def test_mass_normalize(al_beam):
    model = al_beam.modal_model(5)
    scaled = model.shapes * np.array([[3.0], [-0.5], [2.0], [1.0], [7.0]])
    normalized = mass_normalize(scaled, model.grid.mass)
    assert np.diag(gram(normalized, model.grid.mass)) == pytest.approx(1.0)
    assert np.sign(normalized[1, 300]) == np.sign(scaled[1, 300])
