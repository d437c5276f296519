"""The isotropic (9-point Mehrstellen) stencil, `Grid.stencil = "isotropic"`, on plane and rz grids:
its discrete dispersion relation (an exact discrete plane wave stays exact), its stability limit
sqrt(3)/2 from the spectral bound of the actual operator, the refusals (discrete energy
conservation at that limit and its refusal: `test_stability.py`), and gradients (JAX reverse mode = forward mode; the native kernels and the
hand-written lattice adjoint decline it with a reason)."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.lattice import Edges
from difflattice.lattice.coefficients import build_lattice
from difflattice.lattice.grid import make_grid, stability_limit
from difflattice.lattice.medium import Medium
from difflattice.lattice.operators import stencil
from difflattice.observe.analytic import lattice_wavenumber
from difflattice.solver import Stepper, run, simulate
from difflattice.solver.sensors import Sensors
from difflattice.solver.sources import ToneBurst, disc_transducer

jax.config.update("jax_enable_x64", True)

LIMIT = stability_limit("rz", "isotropic")
CLOSED_RZ = Edges.axisymmetric("rigid", "rigid", "rigid")


def _grid(shape, kind="2d", courant=LIMIT, ppw=10.0, c=343.0):
    return make_grid(
        frequency_hz=40e3,
        cells_per_wavelength=ppw,
        c_max_m_s=c,
        shape=shape,
        courant=courant,
        dtype="float64",
        kind=kind,
        stencil="isotropic",
    )


def _operator_matrix(lat, shape):
    n = shape[0] * shape[1]
    basis = jnp.eye(n).reshape(n, *shape)
    return np.asarray(jax.vmap(lambda e: lat.K * stencil(lat, e))(basis).reshape(n, n)).T


def test_limit_value():
    assert LIMIT == pytest.approx(math.sqrt(3) / 2, abs=1e-15)
    assert stability_limit("2d", "isotropic") == LIMIT


N_STEPS = 50


def _evolve(c_lat, ppw, theta, omega):
    n = 150
    grid = _grid((n, n), courant=c_lat, ppw=ppw, c=c_lat)
    k = 2 * math.pi / ppw
    kx, ky = k * math.cos(theta), k * math.sin(theta)
    w = omega(kx, ky)
    x, y = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    stepper = Stepper.build(grid, Medium(c_lat, 1.0), edges=Edges.all("rigid"))
    st = eqx.tree_at(
        lambda s: (s.p, s.p_prev),
        stepper.init(),
        (jnp.asarray(np.cos(kx * x + ky * y)), jnp.asarray(np.cos(kx * x + ky * y + w))),
    )
    res = run(stepper, N_STEPS, state=st)
    exact = np.cos(kx * x + ky * y - w * N_STEPS)
    inner = slice(N_STEPS + 2, n - N_STEPS - 2)  # the 9-point stencil also reaches one cell per step
    return np.abs(np.asarray(res.final.p) - exact)[inner, inner].max()


def _w_iso(c_lat):
    def w(kx, ky):
        sx, sy = math.sin(kx / 2) ** 2, math.sin(ky / 2) ** 2
        return 2 * math.asin(c_lat * math.sqrt(sx + sy - 2 / 3 * sx * sy))

    return w


@pytest.mark.parametrize("c_lat", [0.5, LIMIT])
@pytest.mark.parametrize("theta", [0.0, math.pi / 6, math.pi / 4])
def test_discrete_plane_wave_is_exact(c_lat, theta):
    """sin^2(w/2) = c^2 (sx + sy - (2/3) sx sy): a plane wave of that frequency is exact to round-off."""
    assert _evolve(c_lat, 8.0, theta, _w_iso(c_lat)) < 1e-10


def test_standard_dispersion_is_not_a_solution():
    """The 5-point relation's frequency is not a solution of the isotropic stencil (the test can fail)."""
    c_lat = 0.5

    def w5(kx, ky):
        return 2 * math.asin(c_lat * math.sqrt(math.sin(kx / 2) ** 2 + math.sin(ky / 2) ** 2))

    assert _evolve(c_lat, 4.0, math.pi / 4, w5) > 1e-3


def test_lattice_wavenumber_solves_the_relation():
    c, ppw = 0.8, 12.0
    omega = 2 * math.pi * c / ppw
    for th in (0.0, 0.3, math.pi / 4):
        k = float(lattice_wavenumber(omega, c, th, stencil="isotropic"))
        assert _w_iso(c)(k * math.cos(th), k * math.sin(th)) == pytest.approx(omega, rel=1e-13)
    # direction-independent phase speed to O((k dx)^4): the spread over angles is ~20x below the 5-point one
    ths = np.linspace(0, math.pi / 4, 10)
    spread = np.ptp(lattice_wavenumber(omega, c, ths, stencil="isotropic"))
    spread5 = np.ptp(lattice_wavenumber(omega, 0.7, ths))
    assert spread < spread5 / 10


@pytest.mark.parametrize("kind", ["2d", "rz"])
def test_spectral_bound_gives_the_limit(kind):
    """Uniform density, no obstacles: every eigenvalue of -L is real and in [0, 16/3] (the
    checkerboard symbol; `stability_limit` derives it) for rigid and soft window sides and a speed
    contrast, and the bound is approached with the grid size. With density contrast and cut cells
    the filter loses its 2/3 reduction next to the cut cells (c^2 rho(-L) = 4.23 > 4 at sqrt(3)/2,
    measured): the lattice then keeps the standard limit, where the bound M <= diag(b) gives
    c^2 rho(-L) <= 4, and refuses the isotropic one with the reason."""
    sides = ("rigid", "soft")
    rhos = []
    for n in (12, 24):
        for side in sides:
            edges = Edges.axisymmetric(side, side, side) if kind == "rz" else Edges.all(side)
            g = _grid((n, n), kind)
            c = jnp.asarray(np.where(np.arange(n)[:, None] > n // 2, 300.0, 343.0) * np.ones((1, n)))
            lat = build_lattice(g, Medium(c, 1.2), edges)
            assert lat.uniform_faces
            ev = np.linalg.eigvals(_operator_matrix(lat, (n, n)))
            assert np.abs(ev.imag).max() < 1e-9 * np.abs(ev).max()
            assert ev.real.max() < 1e-9
            assert -ev.real.min() <= 4.0 * (1 + 1e-12)  # c^2 rho(-L) <= 4 at the limit
            if side == "rigid":
                air = build_lattice(g, Medium(343.0, 1.2), edges)
                rhos.append(-np.linalg.eigvals(_operator_matrix(air, (n, n)) / g.courant**2).real.min())
    assert max(rhos) <= 16 / 3 * (1 + 1e-12)
    assert rhos[1] > 5.3 and rhos[1] > rhos[0]
    z, r = np.meshgrid(np.arange(12), np.arange(10), indexing="ij")
    block = (z > 6) & (r > 2) & (r < 6)
    rigid = np.clip(3.5 - np.hypot(z - 3.0, r + 0.5), 0, 1) * (r < 4)
    med = Medium(
        jnp.asarray(np.where(block, 250.0, 343.0)), jnp.asarray(np.where(block, 4.0, 1.2)), rigid=jnp.asarray(rigid)
    )
    edges = CLOSED_RZ if kind == "rz" else Edges.all("rigid")
    with pytest.raises(ValueError, match="isotropic stencil is guaranteed stable only up to the standard limit"):
        build_lattice(_grid((12, 10), kind), med, edges)
    lat = build_lattice(_grid((12, 10), kind, courant=1 / math.sqrt(2)), med, edges)
    ev = np.linalg.eigvals(_operator_matrix(lat, (12, 10)))
    assert np.abs(ev.imag).max() < 1e-8 * np.abs(ev).max()
    assert -ev.real.min() <= 4.0 * (1 + 1e-12)


def test_refusals():
    """Unknown stencils, the paper's boundary model and a standard-stencil courant above its limit
    (the isotropic limit itself and 1.0001 x it, every kind: `test_stability.py`)."""
    with pytest.raises(ValueError, match="stencil = 'mehrstellen'; allowed"):
        make_grid(
            frequency_hz=40e3,
            cells_per_wavelength=10,
            c_max_m_s=343.0,
            shape=(8, 8, 8),
            kind="3d",
            stencil="mehrstellen",
        )
    with pytest.raises(ValueError, match="stencil = 'nine'"):
        make_grid(frequency_hz=40e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(8, 8), stencil="nine")
    with pytest.raises(ValueError, match="boundary_model = 'paper'.*conservative"):
        build_lattice(_grid((8, 8), courant=0.7), Medium(343.0, 1.2, boundary_model="paper"), Edges.all("rigid"))
    # a standard-stencil limit does not carry over: 0.8 is refused there
    with pytest.raises(ValueError, match="1/sqrt\\(2\\)"):
        make_grid(frequency_hz=40e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(8, 8), courant=0.8)


def test_gradients_forward_equals_reverse_and_fast_paths_decline():
    """A disc on an rz grid with PML (the split-field step) and the isotropic stencil: d/d(weights)
    by reverse mode equals forward mode to 1e-9 (f64) (through the native kernels where they run:
    their derivatives are the JAX loop's); `adjoint="lattice"` (the hand-written adjoint is the
    standard stencil's) refuses with the reason."""
    g = _grid((48, 30), "rz", courant=0.8)
    sens = Sensors(probes=[(30, 0), (25, 12)])
    edges = Edges.axisymmetric("rigid", "pml", "pml", thickness_cells=8)

    def loss(w):
        src = disc_transducer(g, radius_m=6.3 * g.dx_m, signal=ToneBurst(40e3, 2), weights=w)
        return jnp.sum(simulate(g, Medium(343.0, 1.2), src, sens, n_steps=90, edges=edges).probes ** 2)

    n = disc_transducer(g, radius_m=6.3 * g.dx_m, signal=ToneBurst(40e3, 2)).n_cells
    w0 = jnp.linspace(0.8, 1.2, n)
    grad = jax.grad(loss)(w0)
    v = jnp.cos(jnp.arange(n, dtype=float))
    _, jv = jax.jvp(loss, (w0,), (v,))
    assert abs(float(jnp.dot(grad, v)) - float(jv)) <= 1e-9 * abs(float(jv))
    rigid = Stepper.build(g, Medium(343.0, 1.2), (), sens, Edges.axisymmetric("rigid", "rigid", "rigid"))
    with pytest.raises(ValueError, match="isotropic stencil"):
        run(rigid, 10, adjoint="lattice")
