"""Stability at the limit on every lattice kind and stencil: a closed lattice conserves the
leapfrog's discrete energy at exactly its stability limit, and a courant or a medium just above
the limit is refused with the kind's own message (`LatticeKind.limit_name`, `limit_formula`).
What differs between the kinds is the table `CLOSED` (each kind's closed window) and the scenes
in `ENERGY`. Kind-specific checks stay with their kinds: the spectral bounds of the operators
(`test_axisym_stability.py`, `test_isotropic_stencil.py`, `test_3d_isotropic.py`), every edge type
and instability detection (`test_stability_energy.py`, `test_3d_lattice.py`).

The energy: sum V (P1 - P0)^2 / K - P1 . V L P0 with V L symmetric (V: the ring volumes on an rz
grid, 1 on the plane and 3-D grids), which the leapfrog conserves exactly (no sources, closed
edges); for the conservative form with zero-flux edges it equals sum (P1 - P0)^2 / K +
sum_faces b dq1 dq0 (summation by parts). Tolerances: float64 round-off (~1e-16 per step, a
random walk: ~1e-13 over 1e5 steps; < 1e-9 asked, < 1e-11 over 2e4 steps, < 1e-10 over 4000);
float32 ~ sqrt(steps) * 6e-8 * 10: 2e-4.
"""

import math
import re

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.lattice import Edges
from difflattice.lattice.coefficients import build_lattice
from difflattice.lattice.geometry3d import Sphere, rasterise3d
from difflattice.lattice.grid import make_grid
from difflattice.lattice.kinds import DEFAULT_COURANT_3D_ISOTROPIC, KINDS
from difflattice.lattice.medium import Medium
from difflattice.lattice.operators import stencil
from difflattice.solver import Stepper, run

CLOSED = {
    "2d": Edges.all("rigid"),
    "rz": Edges.axisymmetric("rigid", "rigid", "rigid"),
    "3d": Edges.all("rigid"),
}


def _grid(shape, kind, stencil_="standard", courant=None, frequency_hz=40e3, ppw=10.0, dtype="float64"):
    """A grid at exactly the stability limit of `kind` and `stencil_` unless `courant` is given."""
    limit = KINDS[kind].stability_limit(stencil_)
    return make_grid(
        frequency_hz=frequency_hz,
        cells_per_wavelength=ppw,
        c_max_m_s=343.0,
        shape=shape,
        courant=limit if courant is None else courant,
        dtype=dtype,
        kind=kind,
        stencil=stencil_,
    )


def _energy(lat, p1, p0):
    v = 1.0 if lat.metric is None else lat.metric.volume
    return float(jnp.sum(v * (p1 - p0) ** 2 / lat.K) - jnp.sum(p1 * v * stencil(lat, p0)))


# --- the scenes: (stepper, initial field, steps, checkpoint, tolerance, peak bound or None) ------
def _two_fluids_box(dtype, tol):
    """A dense slow block (conservative form) in a 64-cell square box, 2e4 steps."""
    n = 64
    g = _grid((n, n), "2d", frequency_hz=50e3, ppw=12, dtype=dtype)
    x, y = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    block = (x > n // 2) & (y > n // 3)
    med = Medium(
        jnp.asarray(np.where(block, 200.0, 343.0), g.jnp_dtype), jnp.asarray(np.where(block, 5.0, 1.2), g.jnp_dtype)
    )
    p0 = jnp.asarray(np.exp(-((x - n / 4) ** 2 + (y - n / 4) ** 2) / 8.0), g.jnp_dtype)
    return Stepper.build(g, med, edges=CLOSED["2d"]), p0, 20_000, None, tol, None


def _air_square():
    """Air in a 32-cell square, 1e5 steps: bounded by the initial peak 1 too."""
    g = _grid((32, 32), "2d", frequency_hz=50e3, ppw=12)
    x, y = np.meshgrid(np.arange(32), np.arange(32), indexing="ij")
    p0 = jnp.asarray(np.exp(-((x - 10) ** 2 + (y - 12) ** 2) / 6.0))
    return Stepper.build(g, Medium(343.0, 1.2), edges=CLOSED["2d"]), p0, 100_000, 1000, 1e-9, 1.0 + 1e-9


def _cylinder(kind, stencil_, obstacles, courant=None):
    """A 12 x 10 section (a closed rz cylinder, or a plane box): air, or a dense slow ring and a
    rounded rigid body with cut cells on the axis side, 1e5 steps."""
    shape = (12, 10)
    z, r = np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij")
    block = (z > shape[0] // 2) & (r > 2) & (r < 6)
    rigid = np.clip(3.5 - np.hypot(z - 3.0, r + 0.5), 0, 1) * (r < 4)  # a rounded body on the axis
    med = (
        Medium(
            jnp.asarray(np.where(block, 250.0, 343.0)), jnp.asarray(np.where(block, 4.0, 1.2)), rigid=jnp.asarray(rigid)
        )
        if obstacles
        else Medium(343.0, 1.2)
    )
    stepper = Stepper.build(_grid(shape, kind, stencil_, courant), med, edges=CLOSED[kind])
    p0 = jnp.asarray(np.exp(-((z - 7.0) ** 2 + r**2) / 4.0) + 0.3 * np.exp(-((z - 9.0) ** 2 + (r - 6.0) ** 2) / 2.0))
    if stepper.lattice.keep is not None:
        p0 = p0 * stepper.lattice.keep
    return stepper, p0, 100_000, 1000, 1e-9, None


def _box_with_sphere():
    """A 12-cell cube: two fluids and a cut-cell rigid sphere, 1e5 steps."""
    n = 12
    g = _grid((n, n, n), "3d")
    x = np.stack(np.meshgrid(*(np.arange(n),) * 3, indexing="ij"), 0)
    slow = x[0] > n // 2
    med = Medium(
        jnp.asarray(np.where(slow, 200.0, 343.0)),
        jnp.asarray(np.where(slow, 5.0, 1.2)),
        rigid=rasterise3d(Sphere(jnp.array([3.3, 8.2, 6.1]) * g.dx_m, jnp.asarray(2.4 * g.dx_m)), g),
    )
    assert float(jnp.sum((med.rigid > 0.05) & (med.rigid < 0.95))) > 10  # really cut cells
    p0 = jnp.asarray(np.exp(-((x[0] - 4) ** 2 + (x[1] - 3) ** 2 + (x[2] - 7) ** 2) / 3.0))
    return Stepper.build(g, med, edges=CLOSED["3d"]), p0, 100_000, 1000, 1e-9, None


def _room_with_a_post():
    """A closed room with a post and a box (voxels) at the 3-D isotropic default courant (0.7 %
    under the limit: obstacles raise the spectral radius by up to 1.4 %), 4000 steps."""
    shape = (14, 13, 12)
    x, y, z = np.meshgrid(*[np.arange(n) for n in shape], indexing="ij")
    post = ((x - 6) ** 2 + (y - 6) ** 2 < 9) | ((x > 9) & (y < 4) & (z < 6))
    g = _grid(shape, "3d", "isotropic", courant=DEFAULT_COURANT_3D_ISOTROPIC)
    stepper = Stepper.build(g, Medium(343.0, 1.2, rigid=jnp.asarray(post, float)), edges=CLOSED["3d"])
    p0 = jnp.asarray(np.exp(-((x - 2.0) ** 2 + (y - 10.0) ** 2 + (z - 5.0) ** 2) / 2.0) * ~post)
    return stepper, p0, 4000, 500, 1e-10, None


ENERGY = {
    "2d-air": _air_square,
    "2d-two_fluids-float64": lambda: _two_fluids_box("float64", 1e-11),
    "2d-two_fluids-float32": lambda: _two_fluids_box("float32", 2e-4),
    "2d-contrast_and_cut_cells": lambda: _cylinder("2d", "standard", True),
    "2d-isotropic-air": lambda: _cylinder("2d", "isotropic", False),
    "rz-air": lambda: _cylinder("rz", "standard", False),
    "rz-contrast_and_cut_cells": lambda: _cylinder("rz", "standard", True),
    "rz-isotropic-air": lambda: _cylinder("rz", "isotropic", False),
    # the isotropic stencil next to cut cells keeps the standard limit (`test_isotropic_stencil.py`)
    "rz-isotropic-contrast_and_cut_cells": lambda: _cylinder("rz", "isotropic", True, courant=1 / math.sqrt(2)),
    "3d-contrast_and_cut_cells": _box_with_sphere,
    "3d-isotropic-post": _room_with_a_post,
}


@pytest.mark.parametrize("scene", list(ENERGY))
def test_closed_lattice_conserves_energy_at_the_limit(scene):
    stepper, p0, n_steps, checkpoint, tol, peak_bound = ENERGY[scene]()
    st = eqx.tree_at(lambda s: (s.p, s.p_prev), stepper.init(), (p0, p0))  # at rest: P1 = P0
    e0 = _energy(stepper.lattice, p0, p0)
    res = run(stepper, n_steps, state=st, checkpoint=checkpoint)
    e1 = _energy(stepper.lattice, res.final.p, res.final.p_prev)
    peaks = np.asarray(res.peak_history)
    assert e0 > 0
    assert abs(e1 - e0) / e0 < tol, (e0, e1)
    assert np.all(np.isfinite(peaks))
    if peak_bound is not None:
        assert peaks.max() < peak_bound  # initial peak 1; energy conservation keeps it below


STENCILS = [
    pytest.param(kind, s, id=kind + ("" if s == "standard" else f"-{s}"))
    for kind in CLOSED
    for s in KINDS[kind].stencils
]


@pytest.mark.parametrize("kind, stencil_", STENCILS)
def test_limit_accepted_and_just_above_refused(kind, stencil_):
    """The limit itself is accepted; 1.0001 x the limit is refused with a message naming the
    kind's limit and the fix; so is a medium 1.0001 x faster than the grid's c_max."""
    k = KINDS[kind]
    shape = (8,) * k.ndim
    g = _grid(shape, kind, stencil_)
    assert g.courant == k.stability_limit(stencil_)
    name = f"exceeds the {k.limit_name(stencil_)} stability limit"
    with pytest.raises(ValueError, match=name + " " + re.escape(k.limit_formula(stencil_)) + ".*Lower `courant`"):
        _grid(shape, kind, stencil_, courant=1.0001 * k.stability_limit(stencil_))
    with pytest.raises(ValueError, match=name):
        build_lattice(g, Medium(343.0 * 1.0001, 1.2), CLOSED[kind])
