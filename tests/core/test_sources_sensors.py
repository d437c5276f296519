"""Sources, sensors and absorption on every lattice kind, the 'only what the scene uses' rule, the
memory refusal before a run of any kind; the rz disc transducer's geometry; the 3-D disc
transducer's cells and weights (area held per cell, rings from a plain dict or a fit report), 3-D
snapshots as slices, and bad input named.

The tests are written once; what differs between the kinds is the table `KINDS` below: each kind's
grid, its open (absorbing) and closed edges, its transducer (a line of cells on the plane and rz
grids, where on rz it is an annulus; a disc facing +x in 3-D) and the cells that the tests use.
The two disc transducers (rz rings, 3-D cells) are built differently and have their own tests.

Tolerances: superposition and the hard source's pressure hold to round-off (1e-12); the first
arrival lies between distance / (1 cell per step) and distance / courant plus a few steps of
rise time; absorption: 2 % (the viscous law is exact at the drive frequency up to O((k dx)^2) of
the lattice). 3-D disc area: each cell's covered area is counted on a 12 x 12 sub-grid per cell
face; the count of a rim cell errs by up to ~1/12 of its area with random sign, so the total over
~60-130 rim cells is within a few tenths of a cell: 0.2 % of a 314-cell disc.
"""

import json
import math
from collections.abc import Callable
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.lattice import Edges
from difflattice.lattice.grid import Grid, make_grid
from difflattice.lattice.medium import Medium
from difflattice.solver import Stepper, simulate
from difflattice.solver.estimate import RunTooLargeError
from difflattice.solver.sensors import Sensors
from difflattice.solver.sources import (
    PointSources,
    ToneBurst,
    disc_cells_3d,
    disc_housing,
    disc_transducer,
    disc_transducer_3d,
    line_transducer,
    ring_fractions,
    rings_from_fit_report,
)


@dataclass(frozen=True)
class Kind:
    """One kind's scenes, in cells. `transducer(grid, centre_cells, weight, injection)`: an
    8-cell-wide transducer centred at `centre_cells` facing +axis 0, driven by a 3-cycle burst."""

    grid: Grid
    open: Edges
    closed: Edges
    transducer: Callable
    centres: tuple[tuple[int, ...], tuple[int, ...], tuple[int, ...]]
    """Two transducers that superpose, and a hard one."""
    probes: tuple[tuple[int, ...], ...]
    point: tuple[int, ...]
    """A point source; the arrival is read 15 and 30 cells from it along axis 0."""
    tube: tuple[tuple[int, ...], Edges, tuple[tuple[int, ...], ...], tuple[int, ...], float]
    """A one-dimensional tube along axis 0 for a plane wave: (shape, edges, source cells, the
    index of the probed cell in the cross-section, absorption in dB/m: strong, so that the effect
    is measurable over a short path, within the lattice's limit on the viscous coefficient, 0.05
    per step, which is ~ 1 / courant: 40 dB/m is 0.045 at 20 cells/wavelength and courant 0.707,
    0.056 at the 3-D courant 0.577, where 30 dB/m is 0.042)."""
    huge: tuple[int, ...]
    """A grid far too large for any machine's memory."""


def _line(grid, centre, weight, injection):
    dx = grid.dx_m
    return line_transducer(
        grid,
        (centre[0] * dx, centre[1] * dx),
        n_cells=8,
        signal=ToneBurst(50e3, 3),
        injection=injection,
        weights=jnp.full(8, weight),
    )


def _disc(grid, centre, weight, injection):
    src = disc_transducer_3d(
        grid,
        tuple(c * grid.dx_m for c in centre),
        (1, 0, 0),
        diameter_m=8 * grid.dx_m,
        signal=ToneBurst(50e3, 3),
        injection=injection,
    )
    return eqx.tree_at(lambda s: s.weights, src, src.weights * weight)


def _grid(shape, kind="2d", **kw):
    return make_grid(
        frequency_hz=50e3, cells_per_wavelength=12, c_max_m_s=343.0, shape=shape, dtype="float64", kind=kind, **kw
    )


_TUBE_2D = ((700, 1), Edges(x_lo="pml", x_hi="pml", y_lo="rigid", y_hi="rigid"), ((100, 0),), (0,), 40.0)
_3D = dict(
    open=Edges.all("pml", thickness_cells=8),
    closed=Edges.all("rigid"),
    transducer=_disc,
    centres=((14, 13, 14), (14, 25, 14), (14, 19, 14)),
    probes=((40, 14, 14), (44, 25, 16)),
    point=(12, 19, 14),
    tube=(
        (700, 3, 3),
        Edges(x_lo="pml", x_hi="pml", y_lo="rigid", y_hi="rigid", z_lo="rigid", z_hi="rigid"),
        tuple((100, j, k) for j in range(3) for k in range(3)),  # the whole cross-section: a plane wave
        (1, 1),
        30.0,
    ),
    huge=(4000, 4000, 4000),
)
KINDS = {
    "2d": Kind(
        grid=_grid((80, 70)),
        open=Edges(thickness_cells=12),
        closed=Edges.all("rigid"),
        transducer=_line,
        centres=((25, 25), (25, 45), (25, 35)),
        probes=((55, 30), (60, 45)),
        point=(20, 35),
        tube=_TUBE_2D,
        huge=(200_000, 200_000),
    ),
    "rz": Kind(
        grid=_grid((80, 70), "rz"),
        open=Edges.axisymmetric(thickness_cells=12),
        closed=Edges.axisymmetric("rigid", "rigid", "rigid"),
        transducer=_line,
        centres=((25, 25), (25, 45), (25, 35)),
        probes=((55, 30), (60, 45)),
        point=(20, 0),  # on the axis
        tube=((700, 1), Edges.axisymmetric("pml", "pml", "rigid"), ((100, 0),), (0,), 40.0),
        huge=(200_000, 200_000),
    ),
    "3d": Kind(grid=_grid((56, 38, 28), "3d"), **_3D),
    "3d-isotropic": Kind(grid=_grid((56, 38, 28), "3d", stencil="isotropic", courant=0.86), **_3D),
}
ALL = list(KINDS)
STANDARD = ["2d", "rz", "3d"]  # where the stencil does not matter


@pytest.mark.parametrize("kind", STANDARD)
def test_soft_sources_superpose(kind):
    k = KINDS[kind]
    g = k.grid
    a_src, b_src = k.transducer(g, k.centres[0], 1.0, "soft"), k.transducer(g, k.centres[1], 2.0, "soft")
    sens = Sensors(probes=k.probes)
    a = simulate(g, Medium(343.0, 1.2), a_src, sens, n_steps=200, edges=k.open).probes
    b = simulate(g, Medium(343.0, 1.2), b_src, sens, n_steps=200, edges=k.open).probes
    ab = simulate(g, Medium(343.0, 1.2), (a_src, b_src), sens, n_steps=200, edges=k.open).probes
    assert float(jnp.abs(ab).max()) > 0
    np.testing.assert_allclose(np.asarray(ab), np.asarray(a + b), atol=1e-12 * float(jnp.abs(ab).max()))


@pytest.mark.parametrize("kind", STANDARD)
def test_hard_source_sets_the_pressure(kind):
    k = KINDS[kind]
    src = k.transducer(k.grid, k.centres[2], 1.0, "hard")
    r = simulate(k.grid, Medium(343.0, 1.2), src, Sensors(probes=src.cells_array), n_steps=80, edges=k.open)
    t = (np.arange(1, 81)) * k.grid.dt_s
    expected = np.asarray(src.signal(jnp.asarray(t)))[:, None] * np.asarray(src.weights)[None, :]
    np.testing.assert_allclose(np.asarray(r.probes), expected, atol=1e-12)


@pytest.mark.parametrize("kind", ALL)
def test_arrival_time_matches_lattice_group_speed(kind):
    """First arrival of a point source's burst at a probe 30 cells away along axis 0: within the
    rise time of the threshold crossing (a few steps) of distance / group speed."""
    k = KINDS[kind]
    src = PointSources(cells=[k.point], signal=ToneBurst(50e3, 2, "rect"), weights=jnp.ones(1), lags_s=jnp.zeros(1))
    sens = Sensors(arrival_threshold_pa=1e-3, p_max=True)
    r = simulate(k.grid, Medium(343.0, 1.2), src, sens, n_steps=150, edges=k.open)
    arr = np.asarray(r.arrival)
    far = arr[(k.point[0] + 30, *k.point[1:])]
    near = arr[(k.point[0] + 15, *k.point[1:])]
    # the wavefront (leading edge) moves at most 1 cell/step and at least at the lattice speed c
    assert 30 <= far <= 30 / k.grid.courant + 6, far
    assert far > near > 0


@pytest.mark.parametrize("kind", STANDARD)
def test_absorption_gives_requested_db_per_m(kind):
    """A plane wave's amplitude at the drive frequency falls by the requested dB/m (viscous law:
    exact for the drive frequency up to O((k dx)^2) of the lattice, 2 % tolerance)."""
    shape, edges, cells, across, alpha = KINDS[kind].tube
    grid = make_grid(
        frequency_hz=50e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=shape, dtype="float64", kind=kind
    )
    n = len(cells)
    src = PointSources(cells=cells, signal=ToneBurst(50e3, 10), weights=jnp.ones(n), lags_s=jnp.zeros(n))
    p1, p2 = 200, 500
    sens = Sensors(phasor_cells=[(p1, *across), (p2, *across)])
    r = simulate(grid, Medium(343.0, 1.2, absorption_db_per_m=alpha), src, sens, n_steps=1600, edges=edges)
    ph = np.asarray(r.phasors)
    measured = 20 * math.log10(abs(ph[0]) / abs(ph[1])) / ((p2 - p1) * grid.dx_m)
    assert measured == pytest.approx(alpha, rel=0.02)
    r0 = simulate(grid, Medium(343.0, 1.2), src, sens, n_steps=1600, edges=edges)
    ph0 = np.asarray(r0.phasors)
    assert abs(20 * math.log10(abs(ph0[0]) / abs(ph0[1]))) < 0.01  # no loss without absorption


def _n_eqns(stepper):
    jaxpr = jax.make_jaxpr(lambda s: stepper.step(s))(stepper.init())
    return len(jaxpr.jaxpr.eqns)


def _grid_sized_inputs(stepper):
    """Arrays of (about) the grid's size that one step reads besides its own state: coefficient
    maps. Each costs a full pass over memory per step."""
    n = math.prod(stepper.grid.shape)
    leaves = jax.tree_util.tree_leaves(eqx.filter(stepper, eqx.is_array))
    return sum(1 for a in leaves if a.size >= 0.9 * n)


@pytest.mark.parametrize("kind", STANDARD)
def test_step_contains_only_what_the_scene_uses(kind):
    k = KINDS[kind]
    g = k.grid
    src = k.transducer(g, k.centres[2], 1.0, "soft")
    plain = Stepper.build(g, Medium(343.0, 1.2), src, Sensors(), k.closed)
    lat = plain.lattice
    assert lat.q_scale is None and lat.bx is None and lat.keep is None and lat.sponge is None and lat.pml is None
    assert jnp.ndim(lat.K) == 0 and lat.eta == 0.0
    n = g.shape[0]  # 80 cells on the plane and rz grids: a medium from 50, a rigid wall from 70
    x = jnp.arange(float(n)).reshape((-1,) + (1,) * (len(g.shape) - 1)) * jnp.ones(g.shape)
    full = Stepper.build(
        g,
        Medium(
            jnp.where(x > n * 5 // 8, 300.0, 343.0),
            jnp.where(x > n * 5 // 8, 2.0, 1.2),
            rigid=(x > n * 7 // 8).astype(jnp.float64),
            absorption_db_per_m=1.0,
        ),
        src,
        Sensors(p_max=True, p_rms=True, phasor_cells=[k.probes[0]]),
        k.open,
    )
    # the plain scene's step reads no coefficient map at all and has far fewer operations
    assert _grid_sized_inputs(plain) == 0
    assert _grid_sized_inputs(full) >= 4  # K, two face conductances, c (and the phasor state)
    assert _n_eqns(plain) < 0.6 * _n_eqns(full)


@pytest.mark.parametrize("kind", STANDARD)
def test_run_that_does_not_fit_is_refused_before_it_starts(kind):
    shape = KINDS[kind].huge
    huge = make_grid(frequency_hz=40e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=shape, kind=kind)
    with pytest.raises(RunTooLargeError, match=" x ".join(map(str, shape)) + ".*estimated memory.*Fix"):
        simulate(huge, Medium(343.0, 1.2), (), Sensors(), n_steps=10, edges=KINDS[kind].open)


# --- the rz disc transducer (rz only) ------------------------------------------------------------
def test_rz_disc_geometry():
    """Ring fractions cover exactly pi a^2 (so the radius is continuous), the face sits on the
    baffle, and a traced radius needs a static ring count."""
    for a in (0.3, 1.0, 5.3, 55.97):
        n = math.ceil(a)
        j = np.arange(n)
        area = np.sum(np.asarray(ring_fractions(a, n)) * (2 * j + 1))  # ring face areas / pi
        assert abs(area - a * a) < 1e-12 * a * a
    g = make_grid(
        frequency_hz=50e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=(60, 40), dtype="float64", kind="rz"
    )
    src = disc_transducer(g, radius_m=5.3 * g.dx_m)
    assert src.n_cells == 6 and src.injection == "velocity" and (np.asarray(src.cells)[:, 0] == 0).all()
    d = jax.grad(lambda r: jnp.sum(disc_transducer(g, radius_m=r, n_rings=8).weights * (2 * jnp.arange(8) + 1)))(
        5.3 * g.dx_m
    )
    assert abs(float(d) - 2 * 5.3 / g.dx_m) < 1e-9 * 2 * 5.3 / g.dx_m  # d(a^2)/da, a in cells per metre
    with pytest.raises(ValueError, match="give n_rings"):
        jax.jit(lambda r: disc_transducer(g, radius_m=r).weights)(0.001)
    with pytest.raises(ValueError, match="rigid z_lo window face"):
        disc_transducer(g, radius_m=0.002, z_m=0.003)
    with pytest.raises(ValueError, match="axisymmetric grid"):
        disc_transducer(
            make_grid(frequency_hz=50e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=(20, 20)), radius_m=0.001
        )
    can = np.asarray(
        disc_housing(g, radius_m=5.3 * g.dx_m, z_m=10 * g.dx_m, baffle="can", depth_m=4.5 * g.dx_m, wall_m=g.dx_m)
    )
    assert can[9, 0] == 1 and can[10, 0] == 0 and abs(can[5, 0] - 0.5) < 1e-12  # 4.5 cells deep behind z = 10
    j = np.arange(40)
    assert abs(np.sum(can[9] * (2 * j + 1)) - 6.3**2) < 1e-9  # the can's outer radius 5.3 + 1 cells
    assert disc_housing(g, radius_m=0.002, z_m=0.0, baffle="rigid") is None


# --- the 3-D disc transducer and snapshots (3-D only) -----------------------------
G = make_grid(frequency_hz=40e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=(60, 50, 50), kind="3d")
H = G.dx_m
C = (30 * H, 25 * H, 24.5 * H)


def test_disc_cells_hold_the_disc_area():
    a = 10.0
    cells, w, lags, area = disc_cells_3d(G, C, (1, 0, 0), 2 * a * H)
    assert set(cells[:, 0]) == {30}  # a disc facing +x lies in one layer of cells
    assert w.sum() == pytest.approx(math.pi * a * a, rel=2e-3)
    r = np.hypot(cells[:, 1] - 25, cells[:, 2] - 24.5)
    assert np.allclose(w[r < a - 1], 1.0)  # cells well inside are fully covered
    assert np.all((w > 0) & (w <= 1 + 1e-12)) and np.all(lags == 0)
    # any orientation: the same area, spread over the layers the tilted plane crosses
    cells2, w2, _, _ = disc_cells_3d(G, C, (1.0, 0.6, -0.3), 2 * a * H)
    assert w2.sum() == pytest.approx(math.pi * a * a, rel=2e-3)
    assert len(set(cells2[:, 0])) > 3


def test_rings_from_a_fit_report_dict():
    edges = [[0.0, 4 * H], [4 * H, 8 * H]]
    cells, w, lags, area = disc_cells_3d(
        G, C, (0, 0, 1), rings={"ring_edges_m": edges, "weights": [1.0, 0.5], "lags_s": [0.0, 2e-6]}
    )
    assert w.sum() == pytest.approx(math.pi * (16 + 0.5 * 48), rel=3e-3)
    r = np.hypot(cells[:, 0] - 30, cells[:, 1] - 25)
    assert np.allclose(lags[r < 3], 0.0) and np.allclose(lags[(r > 5) & (r < 7)], 2e-6)
    assert np.all((lags >= 0) & (lags <= 2e-6 + 1e-18))
    # ring centres instead of edges: edges half-way, the outer one at the diameter
    c2, w2, _, _ = disc_cells_3d(G, C, (0, 0, 1), 16 * H, rings={"radii_m": [2 * H, 6 * H], "weights": [1.0, 0.5]})
    assert w2.sum() == pytest.approx(w.sum(), rel=1e-9)
    src = disc_transducer_3d(
        G, C, (1, 0, 0), diameter_m=16 * H, rings={"radii_m": [2 * H, 6 * H], "weights": [1.0, 0.5]}
    )
    assert src.cells.shape[1] == 3 and float(jnp.sum(src.weights)) == pytest.approx(w.sum(), rel=1e-6)


def test_rings_from_a_disc_fit_report(tmp_path):
    report = {
        "parameters": {
            "diameter_m": 14 * H,
            "weights": [1.0, 0.8, 0.3],
            "ring_fraction": [1.0, 1.0, 0.5],
            "lags_s": [0.0, 1e-6, 2e-6],
        },
        "model": {"dx_m": 3 * H, "n_cells": 3},
    }
    f = tmp_path / "fit_report.json"
    f.write_text(json.dumps(report))
    rings = rings_from_fit_report(f)
    assert np.allclose(rings["ring_edges_m"], [[0, 3 * H], [3 * H, 6 * H], [6 * H, 9 * H]])
    assert np.allclose(rings["weights"], [1.0, 0.8, 0.6])  # the profile: the rim fraction divided out
    src = disc_transducer_3d(G, C, (1, 0, 0), diameter_m=rings["diameter_m"], rings=rings)
    # the disc holds rings 0-1 fully and ring 2 out to r = 7 cells, with the profile weights
    expect = math.pi * (9 * 1.0 + 27 * 0.8 + (49 - 36) * 0.6)
    assert float(jnp.sum(src.weights)) == pytest.approx(expect, rel=3e-3)


def test_bad_discs_are_refused():
    with pytest.raises(ValueError, match="does not fit"):
        disc_cells_3d(G, (2 * H, 25 * H, 25 * H), (0, 0, 1), 20 * H)
    with pytest.raises(ValueError, match="3-D grid"):
        disc_cells_3d(
            make_grid(frequency_hz=40e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=(40, 40)),
            C[:2],
            (1, 0, 0),
            5 * H,
        )
    with pytest.raises(ValueError, match="axis"):
        disc_cells_3d(G, C, (0, 0, 0), 5 * H)
    with pytest.raises(ValueError, match="ring_edges_m"):
        disc_cells_3d(G, C, (1, 0, 0), rings={"weights": [1.0]})
    with pytest.raises(ValueError, match="2 rings but 3 weights"):
        disc_cells_3d(G, C, (1, 0, 0), rings={"ring_edges_m": [[0, H], [H, 2 * H]], "weights": [1, 1, 1]})
    with pytest.raises(ValueError, match="disc_transducer_3d"):
        line_transducer(G, C, n_cells=5)


def test_snapshots_are_slices_unless_asked():
    g = make_grid(frequency_hz=40e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(20, 18, 16), kind="3d")
    src = disc_transducer_3d(g, (10 * g.dx_m, 9 * g.dx_m, 8 * g.dx_m), (1, 0, 0), diameter_m=6 * g.dx_m)
    r = simulate(g, Medium(343.0, 1.2), src, Sensors(snapshot_every=10), n_steps=25, edges=Edges.all("rigid"))
    assert [s.shape for s in r.snapshots] == [(3, 18, 16), (3, 20, 16), (3, 20, 18)]
    assert r.chunk_steps == (10, 20, 25)
    sens = Sensors(snapshot_every=10, snapshot_slices=((2, 8),))
    r2 = simulate(g, Medium(343.0, 1.2), src, sens, n_steps=25, edges=Edges.all("rigid"))
    assert np.array_equal(np.asarray(r2.snapshots[0]), np.asarray(r.snapshots[2]))
    rv = simulate(
        g,
        Medium(343.0, 1.2),
        src,
        Sensors(snapshot_every=10, snapshot_slices="volume"),
        n_steps=25,
        edges=Edges.all("rigid"),
    )
    assert rv.snapshots.shape == (3, 20, 18, 16)
    assert np.array_equal(np.asarray(rv.snapshots[-1][:, :, 8]), np.asarray(r.snapshots[2][-1]))
    with pytest.raises(ValueError, match="outside the grid"):
        simulate(g, Medium(343.0, 1.2), src, Sensors(snapshot_every=10, snapshot_slices=((0, 40),)), n_steps=5)
    with pytest.raises(ValueError, match="3-D grids only"):
        Sensors(snapshot_slices=((0, 1),)).check_inside(
            make_grid(frequency_hz=40e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(20, 18))
        )
    with pytest.raises(ValueError, match="needs 3"):
        simulate(g, Medium(343.0, 1.2), src, Sensors(probes=[(1, 2)]), n_steps=5)


def test_too_strong_absorption_names_the_resolution_that_works():
    """The viscous coefficient grows in proportion to the resolution, so the refusal names the
    largest resolution that takes the absorption (and that one builds), not "refine the grid"."""
    from difflattice.lattice.coefficients import build_lattice

    def grid(cpw):
        return make_grid(frequency_hz=50e3, cells_per_wavelength=cpw, c_max_m_s=343.0, shape=(16, 16), dtype="float64")

    medium = Medium(343.0, 1.2, absorption_db_per_m=30.0)
    with pytest.raises(ValueError, match=r"too strong .* use at most ([0-9.]+) cells per wavelength") as err:
        build_lattice(grid(40.0), medium, Edges.all("rigid"))
    most = float(err.value.args[0].split("use at most ")[1].split(" ")[0])
    assert 20.0 < most < 40.0  # eta = 0.068 at 40 cells per wavelength: 0.05 at 29.5
    build_lattice(grid(0.98 * most), medium, Edges.all("rigid"))  # under the named resolution: accepted
    with pytest.raises(ValueError, match="too strong"):
        build_lattice(grid(1.02 * most), medium, Edges.all("rigid"))
