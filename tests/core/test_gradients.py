"""Differentiability on every lattice kind (float64): forward mode = reverse mode and Taylor
remainders of slope 2, checkpointed reverse mode = plain reverse mode, the adjoint wave equation
(`adjoint="lattice"`) = JAX's reverse mode, jit/vmap over source weights = one run at a time, and
central finite differences. The tests are written once; what differs between the kinds (the
scenes and which parameters they move) is the table `PROBLEMS` below:
- 2-D: a six-cell line transducer with PML edges: its weights and lags, a slower block's speed
  and a smooth rigid circle's radius;
- rz: a disc transducer (8 rings) with the rigid axis and cylindrical PML: ring weights, ring lags
  and the radius; for the adjoint, a disc in a can in front of a slow dense layer (closed, soft and
  sponge window edges: the leapfrog, which the adjoint path supports);
- 3-D: two point sources and a cut-cell rigid sphere in a closed box: weights, lags and the
  sphere's radius at once (one flat parameter vector); JAX's reverse mode runs checkpointed here
  (chunks of 8 steps recomputed in the backward pass) in every check.
A grid split across two devices: `test_sharding.py` (every kind); the 2-D adjoint scenes:
`test_adjoint.py`.

Tolerances (the same on every kind): forward mode, reverse mode, the adjoint wave equation and
checkpointed reverse mode compute one derivative by different arithmetic: agreement to 1e-9
relative (round-off of ~1e4 operations per cell; checkpointing only recomputes the same forward
steps: 1e-10 and 1e-12, see the table). The Taylor remainder |f(x + h v) - f(x) - h g.v| is
O(h^2): slope > 1.8 on a log-log plot over three halvings, and the gradient term dominates (the
remainder < 5 % of the first-order change). Central differences with a relative step of 1e-6 err
by O(h^2) ~ 1e-10 plus round-off 1e-16 / 1e-6: 1e-6 relative.
"""

import functools
from collections.abc import Callable
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.lattice import Edges
from difflattice.lattice.geometry import Circle, rasterise
from difflattice.lattice.geometry3d import Sphere, rasterise3d
from difflattice.lattice.grid import make_grid
from difflattice.lattice.medium import Medium
from difflattice.solver import simulate
from difflattice.solver.sensors import Sensors
from difflattice.solver.sources import PointSources, ToneBurst, disc_housing, disc_transducer, line_transducer


def _loss(result):
    """Probe energy, plus the phasors' (weighted 1e-3) where the scene records them."""
    phasors = 0.0 if result.phasors is None else jnp.sum(jnp.abs(result.phasors) ** 2) * 1e-3
    return jnp.sum(result.probes**2) + phasors


@dataclass(frozen=True)
class Problem:
    """One kind's scenes. Every loss is `f(x, checkpoint=None, adjoint="autodiff")` of an array
    (or a tuple of arrays) `x`, evaluated at its base point."""

    losses: dict[str, tuple[Callable, object]]
    taylor: tuple[str, ...]
    """Losses checked by forward = reverse mode and the Taylor remainder."""
    seed: int
    """Seed of the Taylor test's random direction."""
    checkpoint: object
    """Checkpointing of the reverse mode that the Taylor test and central differences check."""
    checkpointed: tuple[tuple[str, object, float], ...]
    """(loss, checkpoint, relative tolerance to the plain reverse mode's largest entry)."""
    weights: Callable
    """The loss as a function of the source weights alone (a field linear in them)."""
    n_weights: int
    adjoint: tuple[str, int, bool] | None = None
    """(loss, how many gradient entries are not zero, whether the adjoint path runs inside jit) for
    the adjoint wave equation."""
    central_differences: tuple[tuple[int, float], ...] = field(default=())
    """(entry, step) of the loss `adjoint[0]` checked against central differences."""


# --- 2-D -----------------------------------------------------------------------------------------
G2 = make_grid(frequency_hz=50e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(60, 50), dtype="float64")
SENS2 = Sensors(probes=[(45, 25), (40, 35)], phasor_cells=[(50, 20)])
EDGES2 = Edges(thickness_cells=10)


def _run_2d(medium, weights, lags_s, checkpoint, adjoint):
    src = line_transducer(
        G2, (15 * G2.dx_m, 25 * G2.dx_m), n_cells=6, signal=ToneBurst(50e3, 2), weights=weights, lags_s=lags_s
    )
    return _loss(simulate(G2, medium, src, SENS2, n_steps=150, edges=EDGES2, checkpoint=checkpoint, adjoint=adjoint))


def _2d_weights(w, checkpoint=None, adjoint="autodiff"):
    return _run_2d(Medium(343.0, 1.2), w, jnp.zeros(6), checkpoint, adjoint)


def _2d_lags(lags_us, checkpoint=None, adjoint="autodiff"):
    return _run_2d(Medium(343.0, 1.2), jnp.ones(6), lags_us * 1e-6, checkpoint, adjoint)


def _2d_speed(scale, checkpoint=None, adjoint="autodiff"):
    x = jnp.arange(60.0)[:, None] * jnp.ones((1, 50))
    c = 343.0 * jnp.where(x > 30, scale, 1.0)  # a slower block: speed map parameter
    return _run_2d(Medium(c, 1.2), jnp.ones(6), jnp.zeros(6), checkpoint, adjoint)


def _2d_shape(radius_mm, checkpoint=None, adjoint="autodiff"):
    occ = rasterise(Circle(jnp.array([30 * G2.dx_m, 27 * G2.dx_m]), radius_mm * 1e-3), G2, "smooth")
    return _run_2d(Medium(343.0, 1.2, rigid=occ), jnp.ones(6), jnp.zeros(6), checkpoint, adjoint)


# --- rz ------------------------------------------------------------------------------------------
GRZ = make_grid(frequency_hz=50e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(44, 30), dtype="float64", kind="rz")
DX = GRZ.dx_m
RZ_EDGES = Edges.axisymmetric("rigid", "pml", "pml", thickness_cells=8)
RZ_SENS = Sensors(probes=[(25, 0), (30, 12), (20, 18)], phasor_cells=[(28, 3), (33, 9)])
N_RINGS = 8
RADIUS = 5.3 * DX  # the rim inside ring 5: Taylor steps stay inside it (ring fractions are smooth there)
W0 = jnp.linspace(0.7, 1.3, N_RINGS)
L0 = jnp.linspace(0.0, 4.0, N_RINGS)  # microseconds


def _run_rz(
    weights, lags, radius, checkpoint=None, adjoint="autodiff", edges=RZ_EDGES, medium=None, z_m=0.0, baffle="rigid"
):
    src = disc_transducer(
        GRZ,
        radius_m=radius,
        z_m=z_m,
        n_rings=N_RINGS,
        weights=weights,
        lags_s=lags,
        signal=ToneBurst(50e3, 2),
        baffle=baffle,
    )
    med = Medium(343.0, 1.2) if medium is None else medium
    return simulate(GRZ, med, src, RZ_SENS, n_steps=130, edges=edges, checkpoint=checkpoint, adjoint=adjoint)


def _rz_can(args, checkpoint=None, adjoint="autodiff"):
    """A disc in a can (a rigid body of revolution with cut cells) in front of a slow dense layer:
    the can follows the disc's radius (cut cells move with it); the layer's speed and density
    follow c_scale, which also scales the velocity source: every coefficient (K, both face
    conductances) is differentiated."""
    w, lag_us, radius_mm, c_scale = args
    z, _ = np.meshgrid(np.arange(44), np.arange(30), indexing="ij")
    layer = jnp.asarray((z > 30) & (z < 35), jnp.float64)
    can = disc_housing(GRZ, radius_m=radius_mm * 1e-3, z_m=6 * DX, baffle="can", depth_m=3.5 * DX, wall_m=0.7 * DX)
    med = Medium(343.0 * (1 - 0.02 * c_scale) * (1 - 0.2 * layer * c_scale), 1.2 + 2.0 * layer * c_scale, rigid=can)
    edges = Edges.axisymmetric("rigid", "soft", "sponge", thickness_cells=6)
    res = _run_rz(w, lag_us * 1e-6, radius_mm * 1e-3, checkpoint, adjoint, edges, med, z_m=6 * DX, baffle="can")
    return _loss(res) + jnp.sum(res.final.pressure * jnp.sin(jnp.asarray(z) / 5.0)) * 0.1


# --- 3-D -----------------------------------------------------------------------------------------
G3 = make_grid(
    frequency_hz=40e3, cells_per_wavelength=8, c_max_m_s=343.0, shape=(14, 12, 10), kind="3d", dtype="float64"
)
SENS3 = Sensors(probes=[[10, 5, 5], [8, 8, 3]])
X3 = jnp.array([1.0, 0.7, 0.0, 3.0, 2.1 * G3.dx_m * 1e3])  # two weights, two lags (us), the radius (mm)


def _3d(x, checkpoint=None, adjoint="autodiff"):
    occ = rasterise3d(Sphere(jnp.array([7.5, 6.3, 5.2]) * G3.dx_m, x[4] * 1e-3), G3)
    src = PointSources(cells=[[3, 6, 5], [3, 7, 5]], signal=ToneBurst(40e3, 2), weights=x[:2], lags_s=x[2:4] * 1e-6)
    med = Medium(343.0, 1.2, rigid=occ)
    r = simulate(G3, med, src, SENS3, n_steps=40, edges=Edges.all("rigid"), adjoint=adjoint, checkpoint=checkpoint)
    return _loss(r)


PROBLEMS = {
    "2d": Problem(
        losses={
            "weights": (_2d_weights, jnp.linspace(0.5, 1.5, 6)),
            "lags": (_2d_lags, jnp.linspace(0.0, 3.0, 6)),
            "speed": (_2d_speed, jnp.asarray(0.8)),
            "shape": (_2d_shape, jnp.asarray(1.7)),
        },
        taylor=("weights", "lags", "speed", "shape"),
        seed=0,
        checkpoint=None,
        checkpointed=(("weights", "sqrt", 1e-10), ("shape", 7, 1e-10)),
        weights=_2d_weights,
        n_weights=6,
    ),
    "rz": Problem(
        losses={
            "ring weights": (lambda w, **kw: _loss(_run_rz(w, jnp.zeros(N_RINGS), RADIUS, **kw)), W0),
            "ring lags": (lambda lag_us, **kw: _loss(_run_rz(W0, lag_us * 1e-6, RADIUS, **kw)), L0),
            "radius": (lambda r_mm, **kw: _loss(_run_rz(W0, L0 * 1e-6, r_mm * 1e-3, **kw)), jnp.asarray(RADIUS * 1e3)),
            "can": (_rz_can, (W0, L0, jnp.asarray(RADIUS * 1e3), jnp.asarray(1.0))),
        },
        taylor=("ring weights", "ring lags", "radius"),
        seed=1,
        checkpoint=None,
        # the lag gradient at (W0, L0, RADIUS): the scene of the plain gradient the Taylor test caches
        checkpointed=(("ring lags", "sqrt", 1e-12),),
        weights=lambda w: _loss(_run_rz(w, jnp.zeros(N_RINGS), RADIUS)),
        n_weights=N_RINGS,
        # rings 6 and 7 lie outside the 5.3-cell disc: their weights and lags move nothing
        adjoint=("can", 6 + 6 + 1 + 1, True),
    ),
    "3d": Problem(
        losses={"weights, lags, radius": (_3d, X3)},
        taylor=("weights, lags, radius",),
        seed=0,
        checkpoint=8,  # chunks of 8 steps recomputed in the backward pass
        checkpointed=(),
        weights=lambda w: _3d(jnp.concatenate([w, X3[2:]])),
        n_weights=2,
        adjoint=("weights, lags, radius", 5, False),
        # one weight, one lag, the radius; relative steps 1e-6 (the lag: of a 1-us scale)
        central_differences=((1, 1e-6), (3, 1e-6), (4, 1e-6 * G3.dx_m * 1e3)),
    ),
}


@functools.cache
def _value_and_grad(kind, name, checkpoint=None, adjoint="autodiff", jit=False):
    """The loss and its gradient at the base point (cached: several tests compare against it)."""
    f, x0 = PROBLEMS[kind].losses[name]
    vg = jax.value_and_grad(lambda x: f(x, checkpoint=checkpoint, adjoint=adjoint))
    return (jax.jit(vg) if jit else vg)(x0)


def _cases(attribute):
    return [
        pytest.param(kind, item, id=f"{kind}-{item[0] if isinstance(item, tuple) else item}")
        for kind, p in PROBLEMS.items()
        for item in getattr(p, attribute)
    ]


@pytest.mark.parametrize("kind, name", _cases("taylor"))
def test_forward_reverse_and_taylor(kind, name):
    f, x0 = PROBLEMS[kind].losses[name]
    rng = np.random.default_rng(PROBLEMS[kind].seed)
    v = jnp.asarray(rng.normal(size=np.shape(x0)))
    _, g = _value_and_grad(kind, name, PROBLEMS[kind].checkpoint)
    f0, jv = jax.jvp(f, (x0,), (v,))
    rev = jnp.vdot(g, v)
    # forward and reverse mode are the same derivative computed in a different order: round-off
    assert abs(float(jv - rev)) <= 1e-9 * abs(float(rev)), (float(jv), float(rev))
    # Taylor remainder |f(x + h v) - f(x) - h g.v| = O(h^2): slope 2 on a log-log plot
    hs = np.array([2e-3, 1e-3, 5e-4]) * (float(jnp.linalg.norm(x0)) or 1.0) / float(jnp.linalg.norm(v))
    fs = np.array([float(f(x0 + h * v)) for h in hs])
    rem = np.abs(fs - float(f0) - hs * float(rev))
    first = np.abs(fs - float(f0))
    slopes = np.log2(rem[:-1] / rem[1:])
    assert np.all(slopes > 1.8), (slopes, rem, first)
    assert rem[-1] < 0.05 * first[-1]  # the gradient term dominates


@pytest.mark.parametrize("kind, case", _cases("checkpointed"))
def test_checkpointed_gradient_equals_plain(kind, case):
    name, checkpoint, rtol = case
    _, plain = _value_and_grad(kind, name)
    _, ck = _value_and_grad(kind, name, checkpoint)
    assert float(jnp.abs(ck - plain).max()) <= rtol * float(jnp.abs(plain).max())
    np.testing.assert_allclose(np.asarray(ck), np.asarray(plain), rtol=rtol)


@pytest.mark.parametrize("kind", list(PROBLEMS))
def test_jit_and_vmap_over_weights(kind):
    p = PROBLEMS[kind]
    n = p.n_weights
    ws = jnp.stack([jnp.ones(n), 2 * jnp.ones(n), jnp.linspace(0, 1, n)])
    batched = jax.jit(jax.vmap(p.weights))(ws)
    single = jnp.stack([p.weights(w) for w in ws])
    np.testing.assert_allclose(np.asarray(batched), np.asarray(single), rtol=1e-12)
    # linearity of the field in the weights: loss of 2w = 4 x loss of w
    assert float(batched[1]) == pytest.approx(4 * float(batched[0]), rel=1e-12)


@pytest.mark.slow  # ~15-30 s per kind on 2 busy cores, mostly compiling the differentiated programs
@pytest.mark.parametrize("kind", [k for k, p in PROBLEMS.items() if p.adjoint])
def test_lattice_adjoint_equals_autodiff(kind):
    name, n_live, jit = PROBLEMS[kind].adjoint
    ref_val, ref = _value_and_grad(kind, name, PROBLEMS[kind].checkpoint)
    val, got = _value_and_grad(kind, name, None, "lattice", jit)
    assert abs(float(val - ref_val)) <= 1e-12 * abs(float(ref_val))
    leaves = list(zip(jax.tree.leaves(got), jax.tree.leaves(ref)))
    for a, b in leaves:
        a, b = np.ravel(np.asarray(a)), np.ravel(np.asarray(b))
        scale = float(np.abs(b).max())
        assert scale > 0
        assert float(np.abs(a - b).max()) <= 1e-9 * scale, (a, b)
    assert sum(int(np.count_nonzero(b)) for _, b in leaves) == n_live
    for a, b in leaves:  # every entry that is not zero, to 1e-9 of itself
        live = np.asarray(b) != 0
        np.testing.assert_allclose(np.asarray(a)[live], np.asarray(b)[live], rtol=1e-9)


@pytest.mark.parametrize("kind, case", _cases("central_differences"))
def test_central_differences(kind, case):
    i, h = case
    name = PROBLEMS[kind].adjoint[0]
    f, x0 = PROBLEMS[kind].losses[name]
    _, g = _value_and_grad(kind, name, PROBLEMS[kind].checkpoint)
    fd = (float(f(x0.at[i].add(h))) - float(f(x0.at[i].add(-h)))) / (2 * h)
    assert fd == pytest.approx(float(g[i]), rel=1e-6), (i, fd, float(g[i]))


def test_point_source_gradient_on_the_axis():
    """rz only (the kind with an axis): a soft point source in the axis cell: forward = reverse
    (the axis ring's metric factor 0 on its inner face must not produce NaNs in either mode)."""
    assert GRZ.kind.has_axis_edge

    def f(w):
        src = PointSources(cells=[(20, 0)], signal=ToneBurst(50e3, 2), weights=w, lags_s=jnp.zeros(1))
        return _loss(simulate(GRZ, Medium(343.0, 1.2), src, RZ_SENS, n_steps=130, edges=RZ_EDGES))

    g = jax.grad(f)(jnp.ones(1))
    _, jv = jax.jvp(f, (jnp.ones(1),), (jnp.ones(1),))
    assert np.isfinite(float(g[0])) and abs(float(jv - g[0])) <= 1e-9 * abs(float(g[0]))
