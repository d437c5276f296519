"""The adjoint-wave-equation reverse mode (`adjoint="lattice"`) gives JAX's reverse-mode
gradients (the reference path) for source weights and lags, a medium map and a shape, in every
scene kind it supports; unsupported scenes are refused with the reason."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.lattice import Edges
from difflattice.lattice.geometry import Circle, rasterise
from difflattice.lattice.grid import make_grid
from difflattice.lattice.medium import Medium
from difflattice.solver import simulate
from difflattice.solver.sensors import Sensors
from difflattice.solver.sources import ToneBurst, line_transducer

G = make_grid(frequency_hz=50e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(48, 40), dtype="float64")
X = jnp.arange(48.0)[:, None] * jnp.ones((1, 40))
SENS = Sensors(probes=[(30, 20), (36, 12)], phasor_cells=[(28, 25), (33, 18), (40, 30)])
N = 97  # not a multiple of the chunk: exercises the remainder chunk


def _scene(kind):
    if kind == "homogeneous":
        return (lambda c: Medium(c, 1.2)), Edges.all("rigid"), "soft"
    if kind == "conservative":
        return (
            (
                lambda c: Medium(
                    c,
                    jnp.where(X > 30, 2.0, 1.2),
                    rigid=(X > 42).astype(jnp.float64),
                    soft=((X < 4) & (X > 1)).astype(jnp.float64),
                )
            ),
            Edges(x_lo="soft", x_hi="rigid", y_lo="rigid", y_hi="soft"),
            "soft",
        )
    if kind == "speed_zero":
        return (
            (lambda c: Medium(c, 1.2, rigid=(X > 40).astype(jnp.float64), boundary_model="speed_zero")),
            Edges.all("rigid"),
            "hard",
        )
    if kind == "sponge":
        return (lambda c: Medium(c, 1.2)), Edges.all("sponge", thickness_cells=6), "soft"
    raise AssertionError(kind)


def _loss(kind, adjoint):
    make_medium, edges, injection = _scene(kind)

    def loss(w, lag, c):
        src = line_transducer(
            G,
            (14 * G.dx_m, 20 * G.dx_m),
            n_cells=5,
            signal=ToneBurst(50e3, 2),
            weights=w,
            lags_s=lag,
            injection=injection,
        )
        r = simulate(G, make_medium(c), src, SENS, n_steps=N, edges=edges, adjoint=adjoint, checkpoint=10)
        return (
            jnp.sum(r.probes**2)
            + jnp.sum(jnp.abs(r.phasors) ** 2) * 1e-3
            + jnp.sum(r.final.pressure * jnp.sin(X / 5)) * 0.1
        )

    return loss


@pytest.mark.parametrize("kind", ["homogeneous", "conservative", "speed_zero", "sponge"])
def test_lattice_adjoint_equals_autodiff(kind):
    w = jnp.linspace(0.8, 1.2, 5)
    lag = jnp.linspace(0.0, 3e-6, 5)
    c = 343.0 - 20.0 * jnp.exp(-((X - 26) ** 2 + (jnp.arange(40.0)[None] - 20) ** 2) / 30)
    ref_val, ref = jax.value_and_grad(_loss(kind, "autodiff"), argnums=(0, 1, 2))(w, lag, c)
    val, got = jax.jit(jax.value_and_grad(_loss(kind, "lattice"), argnums=(0, 1, 2)))(w, lag, c)
    # same arithmetic reordered: agreement to round-off of the float64 sums (~1e-13 relative)
    assert abs(float(val - ref_val)) <= 1e-12 * abs(float(ref_val))
    for name, a, b in zip(("weights", "lags", "speed map"), got, ref):
        scale = float(jnp.abs(b).max())
        assert scale > 0, name
        err = float(jnp.abs(a - b).max())
        assert err <= 1e-9 * scale, f"{kind} {name}: {err:.3g} vs scale {scale:.3g}"


def test_lattice_adjoint_shape_gradient():
    def loss(r_m, adjoint):
        occ = rasterise(Circle(jnp.array([30 * G.dx_m, 20 * G.dx_m]), r_m), G, "smooth")
        src = line_transducer(G, (12 * G.dx_m, 20 * G.dx_m), n_cells=5, signal=ToneBurst(50e3, 2))
        r = simulate(G, Medium(343.0, 1.2, rigid=occ), src, SENS, n_steps=80, edges=Edges.all("rigid"), adjoint=adjoint)
        return jnp.sum(r.probes**2)

    r0 = jnp.asarray(3.3 * G.dx_m)
    a = jax.grad(lambda r: loss(r, "lattice"))(r0)
    b = jax.grad(lambda r: loss(r, "autodiff"))(r0)
    assert abs(float(b)) > 0 and abs(float(a - b)) <= 1e-9 * abs(float(b))


def test_unsupported_scenes_are_refused_with_the_reason():
    src = line_transducer(G, (14 * G.dx_m, 20 * G.dx_m), n_cells=5)
    with pytest.raises(ValueError, match="PML"):
        simulate(G, Medium(343.0, 1.2), src, SENS, n_steps=10, edges=Edges(thickness_cells=6), adjoint="lattice")
    with pytest.raises(ValueError, match="p_max"):
        simulate(
            G, Medium(343.0, 1.2), src, Sensors(p_max=True), n_steps=10, edges=Edges.all("rigid"), adjoint="lattice"
        )
    # "auto" falls back to JAX's reverse mode and gives the same numbers
    a = simulate(G, Medium(343.0, 1.2), src, SENS, n_steps=30, edges=Edges(thickness_cells=6), adjoint="auto")
    b = simulate(G, Medium(343.0, 1.2), src, SENS, n_steps=30, edges=Edges(thickness_cells=6))
    np.testing.assert_array_equal(np.asarray(a.probes), np.asarray(b.probes))
