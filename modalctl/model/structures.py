"""Analytic structures: Euler-Bernoulli beams, a simply supported Kirchhoff plate, piezo patches.

Coordinates are centred: a beam of length L spans x in [-L/2, L/2], a plate a x b spans
[-a/2, a/2] x [-b/2, b/2], as in the thesis. Mode shapes are mass-normalized
(``integral rho A phi_k phi_l dx = delta_kl``, unit 1/sqrt(kg)). Actuator gains follow the
pin-force model of a bonded piezo patch: the patch applies equal and opposite moments at
its ends, so its modal gain is the moment per volt times the slope difference of the mode
between the patch ends (Eq 2.19 integrated by parts).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import brentq

from .modes import Grid, ModalModel, ModelError

__all__ = ["Piezo", "BeamPatch", "PlatePatch", "Beam", "Plate", "BOUNDARIES"]

#: The field (V/m) a drive may reach against a PZT-5A patch's poling direction without starting to
#: depolarize it: 0.35 MV/m, the low end of the 0.35-0.5 MV/m given for soft PZT (PZT-5A) against the
#: poling (along it about 1-2 MV/m is tolerated; the coercive field is about 1.2 MV/m). A plan's
#: voltages swing both ways, so the side against the poling binds. The thesis names its amplifier
#: (NF HSA 4051, section 4.1) but neither its rails nor the patches' limit, so the patch sets it.
PZT5A_DEPOLARIZATION_FIELD = 0.35e6

#: Beam end conditions: clamped-clamped, pinned-pinned, free-free, clamped-free.
BOUNDARIES = ("clamped-clamped", "pinned-pinned", "free-free", "clamped-free")


@dataclass(frozen=True)
class Piezo:
    """Piezo patch material (defaults: PZT-5A, 0.2 mm thick).

    Attributes
    ----------
    d31 : float
        Magnitude of the transverse piezoelectric coefficient (m/V).
    modulus : float
        Young's modulus of the patch (Pa).
    thickness : float
        Patch thickness (m).
    depolarization_field : float
        The largest field (V/m) a drive may put across the patch against its poling
        (:data:`PZT5A_DEPOLARIZATION_FIELD`); it sets :attr:`safe_voltage`. Not in the repr: it
        changes no mode, and the finite-element cache keys on the repr.
    """

    d31: float = 171e-12
    modulus: float = 61e9
    thickness: float = 0.2e-3
    depolarization_field: float = field(default=PZT5A_DEPOLARIZATION_FIELD, repr=False)

    def __post_init__(self):
        for name in ("d31", "modulus", "thickness", "depolarization_field"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ModelError(f"piezo.{name}: must be positive and finite, got {value!r}")

    @property
    def safe_voltage(self) -> float:
        """The largest drive voltage (V, peak, either sign) the patch takes without depolarizing:
        its depolarization field times its thickness (70 V for 0.2 mm of PZT-5A)."""
        return self.depolarization_field * self.thickness

    def voltage_meta(self) -> dict:
        """What a model's ``meta`` says of its actuators' safe voltage (``voltage_limit_v``, the
        default ``--voltage-limit`` of ``modalctl run``) and where it comes from."""
        return {"voltage_limit_v": self.safe_voltage,
                "voltage_limit_source": f"piezo patches {self.thickness * 1e3:g} mm thick at "
                                        f"{self.depolarization_field / 1e6:g} MV/m against their poling "
                                        f"(depolarization; PZT-5A: 0.35-0.5 MV/m)"}

    def moment_per_volt(self, host_modulus: float, host_thickness: float) -> float:
        """Bending moment per unit patch width per volt (N m / m / V = N/V), pin-force model.

        The patch's free strain ``d31 V / t_p`` is shared with the host surface through a
        force F = E_p t_p Lambda psi / (psi + 4), psi = E_h t_h / (E_p t_p), acting at the
        host surface, hence a moment F t_h / 2 about the neutral axis (Crawley and de Luis).
        """
        psi = host_modulus * host_thickness / (self.modulus * self.thickness)
        force_per_volt = self.modulus * self.d31 * psi / (psi + 4.0)  # N per metre of width per volt
        return force_per_volt * host_thickness / 2.0


@dataclass(frozen=True)
class BeamPatch:
    """A patch bonded on a beam between ``start`` and ``stop`` (m, centred coordinates)."""

    start: float
    stop: float
    name: str = ""


@dataclass(frozen=True)
class PlatePatch:
    """A rectangular patch on a plate: ``xlim`` and ``ylim`` are (low, high) in metres."""

    xlim: tuple[float, float]
    ylim: tuple[float, float]
    name: str = ""


def _characteristic_roots(boundary: str, count: int) -> np.ndarray:
    """Dimensionless wavenumbers lambda_n = beta_n L of the first ``count`` elastic modes."""
    if boundary == "pinned-pinned":
        return np.pi * np.arange(1, count + 1)
    if boundary in ("clamped-clamped", "free-free"):
        f, brackets = (lambda z: np.cos(z) - 1 / np.cosh(z)), [(n * np.pi, (n + 1) * np.pi) for n in range(1, count + 1)]
    else:  # clamped-free
        f, brackets = (lambda z: np.cos(z) + 1 / np.cosh(z)), [(max(n - 1, 1e-9) * np.pi, n * np.pi) for n in range(1, count + 1)]
    return np.array([brentq(f, lo, hi, xtol=1e-14) for lo, hi in brackets])


def _beam_shape(boundary: str, lam: float, u: np.ndarray, derivative: int) -> np.ndarray:
    """Shape phi(u) on u = s / L in [0, 1] with integral of phi^2 du = 1, or its d-th derivative
    with respect to u. Hyperbolic terms are written as decaying exponentials so that high modes
    (lambda ~ 70) keep full precision instead of cancelling cosh - sinh."""
    d = derivative
    if boundary == "pinned-pinned":
        return np.sqrt(2.0) * lam**d * np.sin(lam * u + d * np.pi / 2)
    e = np.exp(-lam)
    if boundary == "clamped-free":
        q = (e + np.cos(lam) + np.sin(lam)) / (1 + e * e + 2 * e * np.cos(lam))
    else:
        q = (np.cos(lam) - np.sin(lam) - e) / (1 - e * e - 2 * e * np.sin(lam))
    sigma = 1 - 2 * q * e  # cosh(lam u) - sigma sinh(lam u) = q e^{lam(u-1)} + p e^{-lam u}
    p = (1 + sigma) / 2
    hyper = lam**d * (q * np.exp(lam * (u - 1)) + (-1) ** d * p * np.exp(-lam * u))
    trig = lam**d * (np.cos(lam * u + d * np.pi / 2) - sigma * np.sin(lam * u + d * np.pi / 2))
    return hyper + trig if boundary == "free-free" else hyper - trig


@dataclass(frozen=True)
class Beam:
    """Uniform Euler-Bernoulli beam.

    Attributes
    ----------
    length, width, thickness : float
        Dimensions (m).
    modulus : float
        Young's modulus (Pa).
    density : float
        Density (kg/m^3).
    boundary : str
        One of :data:`BOUNDARIES`.
    """

    length: float
    width: float
    thickness: float
    modulus: float
    density: float
    boundary: str = "clamped-clamped"

    def __post_init__(self):
        if self.boundary not in BOUNDARIES:
            raise ModelError(f"boundary: unknown {self.boundary!r}; choose one of {', '.join(BOUNDARIES)}")
        for name in ("length", "width", "thickness", "modulus", "density"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise ModelError(f"beam.{name}: must be positive and finite, got {value!r}")

    @property
    def mass_per_length(self) -> float:
        """rho A (kg/m)."""
        return self.density * self.width * self.thickness

    def wavenumbers(self, n_modes: int) -> np.ndarray:
        """beta_n (1/m) of the first ``n_modes`` elastic modes."""
        return _characteristic_roots(self.boundary, n_modes) / self.length

    def frequencies(self, n_modes: int) -> np.ndarray:
        """Analytic resonance frequencies (Hz) of the first ``n_modes`` elastic modes."""
        stiffness = self.modulus * self.width * self.thickness**3 / 12
        return self.wavenumbers(n_modes) ** 2 * np.sqrt(stiffness / self.mass_per_length) / (2 * np.pi)

    def shapes(self, x, modes, derivative: int = 0) -> np.ndarray:
        """Mass-normalized elastic mode shapes (or their x-derivatives) at positions ``x`` (m).

        Parameters
        ----------
        x : array_like, shape (n,)
        modes : int or sequence of int
            Number of modes, or 1-based elastic mode numbers.
        derivative : int
            Order of the derivative with respect to x.

        Returns
        -------
        ndarray, shape (k, n)
        """
        numbers = np.arange(1, modes + 1) if np.isscalar(modes) else np.asarray(modes, dtype=int)
        lams = _characteristic_roots(self.boundary, int(numbers.max()))[numbers - 1]
        u = (np.asarray(x, dtype=float) + self.length / 2) / self.length
        scale = 1 / (np.sqrt(self.mass_per_length * self.length) * self.length**derivative)
        return np.array([_beam_shape(self.boundary, lam, u, derivative) for lam in lams]) * scale

    def rigid_shapes(self, x) -> np.ndarray:
        """Mass-normalized rigid-body modes (translation, rotation), shape (2, n); empty unless free-free."""
        x = np.asarray(x, dtype=float)
        if self.boundary != "free-free":
            return np.zeros((0, x.size))
        m = self.mass_per_length * self.length
        return np.vstack([np.full(x.size, 1 / np.sqrt(m)), x * np.sqrt(12 / (m * self.length**2))])

    def grid(self, n_points: int = 1001) -> Grid:
        """Uniform grid over the whole beam with Simpson mass weights."""
        return Grid.line(-self.length / 2, self.length / 2, n_points, self.mass_per_length)

    def patch_gains(self, patches, modes, piezo: Piezo = Piezo()) -> np.ndarray:
        """Modal gains (sqrt(kg) m / (s^2 V)) of ``patches`` on ``modes``, shape (k, a)."""
        moment = piezo.moment_per_volt(self.modulus, self.thickness) * self.width
        cols = [moment * (self.shapes([p.stop], modes, 1)[:, 0] - self.shapes([p.start], modes, 1)[:, 0])
                for p in patches]
        k = modes if np.isscalar(modes) else len(modes)
        return np.column_stack(cols) if cols else np.zeros((k, 0))

    def modal_model(self, modes=10, *, n_points: int = 1001, patches=(), sensors=(), frequencies=None,
                    damping=0.01, piezo: Piezo = Piezo(), meta: dict | None = None) -> ModalModel:
        """Build the modal model of this beam.

        Parameters
        ----------
        modes : int or sequence of int
            Count, or 1-based elastic mode numbers (kept as the model's labels).
        n_points : int
            Grid points over the beam.
        patches : sequence of BeamPatch
        sensors : sequence of float
            Positions (m) of point velocity sensors.
        frequencies : array_like, optional
            Measured frequencies (Hz) to use instead of the analytic ones.
        damping : float or array_like
            Damping ratios.
        """
        numbers = np.arange(1, modes + 1) if np.isscalar(modes) else np.asarray(modes, dtype=int)
        grid = self.grid(n_points)
        freqs = self.frequencies(int(numbers.max()))[numbers - 1] if frequencies is None else frequencies
        info = {"structure": "beam", "boundary": self.boundary, "length_m": self.length, "width_m": self.width,
                "thickness_m": self.thickness, "modulus_Pa": self.modulus, "density_kg_m3": self.density,
                "actuators": [{"name": p.name or f"patch{i + 1}", "start_m": p.start, "stop_m": p.stop}
                              for i, p in enumerate(patches)],
                "sensors": [{"name": f"sensor{i + 1}", "position_m": [float(s)]} for i, s in enumerate(sensors)],
                "piezo": {"d31_m_V": piezo.d31, "modulus_Pa": piezo.modulus, "thickness_m": piezo.thickness},
                **piezo.voltage_meta()}
        info.update(meta or {})
        return ModalModel(
            grid=grid, frequencies=freqs, damping=np.broadcast_to(damping, numbers.shape),
            shapes=self.shapes(grid.x, numbers), actuator_gains=self.patch_gains(patches, numbers, piezo),
            sensor_gains=self.shapes(np.asarray(sensors, float), numbers) if len(sensors) else None,
            labels=numbers, rigid_shapes=self.rigid_shapes(grid.x), meta=info)


@dataclass(frozen=True)
class Plate:
    """Simply supported rectangular Kirchhoff plate, ``a`` along x and ``b`` along y (m)."""

    a: float
    b: float
    thickness: float
    modulus: float
    density: float
    poisson: float = 0.3

    def __post_init__(self):
        for name in ("a", "b", "thickness", "modulus", "density"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise ModelError(f"plate.{name}: must be positive and finite, got {value!r}")
        if not 0 <= self.poisson < 0.5:
            raise ModelError(f"plate.poisson: must lie in [0, 0.5), got {self.poisson!r}")

    @property
    def mass_per_area(self) -> float:
        """rho h (kg/m^2)."""
        return self.density * self.thickness

    @property
    def rigidity(self) -> float:
        """Bending stiffness ``E h^3 / (12 (1 - nu^2))`` (N m)."""
        return self.modulus * self.thickness**3 / (12 * (1 - self.poisson**2))

    def mode_indices(self, n_modes: int) -> np.ndarray:
        """(m, n) half-wave numbers of the ``n_modes`` lowest modes, sorted by frequency, shape (k, 2)."""
        top = n_modes + 1
        mm, nn = np.meshgrid(np.arange(1, top + 1), np.arange(1, top + 1), indexing="ij")
        pairs = np.column_stack([mm.ravel(), nn.ravel()])
        key = (pairs[:, 0] / self.a) ** 2 + (pairs[:, 1] / self.b) ** 2
        order = np.lexsort((pairs[:, 1], pairs[:, 0], key))
        return pairs[order[:n_modes]]

    def frequencies(self, indices) -> np.ndarray:
        """Resonance frequencies (Hz) of modes with half-wave numbers ``indices`` (k, 2)."""
        idx = np.asarray(indices, dtype=float)
        lam = np.pi**2 * ((idx[:, 0] / self.a) ** 2 + (idx[:, 1] / self.b) ** 2)
        return lam * np.sqrt(self.rigidity / self.mass_per_area) / (2 * np.pi)

    def shapes(self, points, indices) -> np.ndarray:
        """Mass-normalized shapes at ``points`` (n, 2) in metres, shape (k, n)."""
        pts = np.atleast_2d(np.asarray(points, dtype=float))
        idx = np.asarray(indices, dtype=float)
        s, t = pts[:, 0] + self.a / 2, pts[:, 1] + self.b / 2
        scale = 2 / np.sqrt(self.mass_per_area * self.a * self.b)
        return scale * np.sin(np.pi * idx[:, :1] * s / self.a) * np.sin(np.pi * idx[:, 1:] * t / self.b)

    def grid(self, nx: int = 100, ny: int = 70) -> Grid:
        """Uniform grid over the plate with tensor Simpson mass weights."""
        return Grid.rectangle((-self.a / 2, self.a / 2), (-self.b / 2, self.b / 2), nx, ny, self.mass_per_area)

    def patch_gains(self, patches, indices, piezo: Piezo = Piezo()) -> np.ndarray:
        """Modal gains of rectangular patches (isotropic pin-force moments), shape (k, a).

        The moment line density m acts along the patch edges; its generalized force on mode
        (m, n) is ``m * C (a_m/b_n + b_n/a_m)(cos a_m s2 - cos a_m s1)(cos b_n t1 - cos b_n t2)``.
        """
        idx = np.asarray(indices, dtype=float)
        km, kn = np.pi * idx[:, 0] / self.a, np.pi * idx[:, 1] / self.b
        scale = 2 / np.sqrt(self.mass_per_area * self.a * self.b)
        moment = piezo.moment_per_volt(self.modulus, self.thickness)
        cols = []
        for p in patches:
            (s1, s2), (t1, t2) = np.add(p.xlim, self.a / 2), np.add(p.ylim, self.b / 2)
            cols.append(moment * scale * (km / kn + kn / km) * (np.cos(km * s2) - np.cos(km * s1))
                        * (np.cos(kn * t1) - np.cos(kn * t2)))
        return np.column_stack(cols) if cols else np.zeros((len(idx), 0))

    def modal_model(self, n_modes: int = 21, *, nx: int = 100, ny: int = 70, patches=(), sensors=(),
                    damping=0.01, piezo: Piezo = Piezo(), meta: dict | None = None) -> ModalModel:
        """Build the modal model of the ``n_modes`` lowest plate modes on an ``nx`` x ``ny`` grid."""
        indices = self.mode_indices(n_modes)
        grid = self.grid(nx, ny)
        info = {"structure": "plate", "boundary": "simply-supported", "a_m": self.a, "b_m": self.b,
                "thickness_m": self.thickness, "modulus_Pa": self.modulus, "density_kg_m3": self.density,
                "poisson": self.poisson, "mode_indices": indices.tolist(),
                "actuators": [{"name": p.name or f"patch{i + 1}", "xlim_m": list(p.xlim), "ylim_m": list(p.ylim)}
                              for i, p in enumerate(patches)],
                "sensors": [{"name": f"sensor{i + 1}", "position_m": list(map(float, s))}
                            for i, s in enumerate(sensors)], **piezo.voltage_meta()}
        info.update(meta or {})
        return ModalModel(
            grid=grid, frequencies=self.frequencies(indices), damping=np.broadcast_to(damping, (n_modes,)),
            shapes=self.shapes(grid.points, indices), actuator_gains=self.patch_gains(patches, indices, piezo),
            sensor_gains=self.shapes(np.asarray(sensors, float), indices) if len(sensors) else None,
            meta=info)
