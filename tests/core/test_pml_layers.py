"""PML layers that cost only where they are: the stepper runs the leapfrog on the whole grid and
the split-field form on the layer's boxes only (`PML.boxes`, `StaggeredState.layers`).

References:
- the split-field form over the whole grid (the stepper's form before the layered state, written
  out below from the same operators): the two are the same scheme in exact arithmetic, so in
  float64 they agree to rounding, |layered - full| <= n_steps * 16 * eps * peak (16 roundings a
  cell and step, added at most linearly by a neutrally stable scheme; as tests/core/test_native.py);
- the leapfrog without PML: before a wave reaches the layer the interior's arithmetic is the
  lossless leapfrog's, operation for operation, so the fields are bit-identical;
- the layer geometry: every cell outside the boxes has sigma = 0 on itself and its faces, and the
  boxes are disjoint and cover every damped cell.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.lattice import Edges
from difflattice.lattice.coefficients import layer_boxes
from difflattice.lattice.grid import make_grid
from difflattice.lattice.medium import Medium
from difflattice.lattice.operators import divergence, face_gradient
from difflattice.solver import Sensors, StaggeredState, Stepper, run
from difflattice.solver.sources import PointSources, ToneBurst
from difflattice.solver.stepper import cell_index

jax.config.update("jax_enable_x64", True)


def _full_split_field(stepper: Stepper, n_steps: int):
    """The split-field PML form on every cell (P = sum of parts, a face flux per axis, soft
    sources' running sums split evenly over the parts, the rz r_hi ring correction): returns the
    pressure after each step, (n_steps, *grid)."""
    lat, grid = stepper.lattice, stepper.grid
    pml = lat.pml
    shape = tuple(grid.shape)
    ndim = len(shape)
    dt = grid.jnp_dtype
    faces = lambda a: jnp.zeros(tuple(n + 1 if i == a else n for i, n in enumerate(shape)), dt)
    rad = pml.radial
    st0 = (
        tuple(jnp.zeros(shape, dt) for _ in range(ndim)),
        tuple(faces(a) for a in range(ndim)),
        tuple(jnp.zeros(s.n_cells, dt) for s in stepper.sources if s.adds),
        jnp.zeros(shape, dt),
        None if rad is None else jnp.zeros((shape[0], rad.width), dt),
    )

    def step(st, n_next):
        parts, fluxes, acc, p_prev, c_r = st
        p = sum(parts[1:], parts[0])
        p_eff = p if lat.eta == 0 else (1 + lat.eta) * p - lat.eta * p_prev
        q = p_eff if lat.q_scale is None else lat.q_scale * p_eff
        new_w = [
            pml.factors(a, "face")[0] * fluxes[a] + pml.factors(a, "face")[1] * face_gradient(lat, q, a)
            for a in range(ndim)
        ]
        new_p = []
        for a in range(ndim):
            div = divergence(lat, new_w[a], a)
            if a == 1 and rad is not None:
                w = rad.width
                wy, old = new_w[1], fluxes[1]
                c_r = rad.decay * c_r + rad.drive * (
                    wy[:, -w:] + wy[:, -w - 1 : -1] + old[:, -w:] + old[:, -w - 1 : -1]
                )
                div = div + jnp.pad(c_r, ((0, 0), (div.shape[1] - w, 0)))
            ac, bc = pml.factors(a, "cell")
            new_p.append(ac * parts[a] + bc * (lat.K * div))
        if lat.keep is not None:
            new_p = [lat.keep * x for x in new_p]
        t = n_next.astype(dt) * grid.dt_s
        acc, k = list(acc), 0
        for src in stepper.sources:
            v = src.injected(t, grid.dt_s, None).astype(dt)
            c = cell_index(src.cells)
            if src.adds:
                acc[k] = acc[k] + v
                new_p = [x.at[c].add(acc[k] / ndim) for x in new_p]
                k += 1
            else:
                new_p = [x.at[c].set(v / ndim) for x in new_p]
        p_new = sum(new_p[1:], new_p[0])
        return (tuple(new_p), tuple(new_w), tuple(acc), p, c_r), p_new

    _, ps = jax.lax.scan(step, st0, jnp.arange(1, n_steps + 1, dtype=jnp.int32))
    return ps


def _sigma_cells(stepper: Stepper):
    """Cells whose PML factors differ from 1 on the cell or one of its faces, any axis."""
    pml, shape = stepper.lattice.pml, tuple(stepper.grid.shape)
    out = np.zeros(shape, bool)
    for axis in range(len(shape)):
        for where in ("cell", "face"):
            a = np.asarray(pml.factors(axis, where)[0]).reshape(-1)
            off = a != 1
            if where == "face":
                off = off[:-1] | off[1:]
            out |= off.reshape(tuple(-1 if i == axis else 1 for i in range(len(shape))))
    return out


def _layered(stepper: Stepper, n_steps: int):
    def step(st, _):
        st, _ = stepper.step(st)
        return st, st.pressure

    _, ps = jax.lax.scan(step, stepper.init(), None, length=n_steps)
    return ps


def _scene(case: str):
    if case == "3d":
        g = make_grid(
            frequency_hz=50e3, cells_per_wavelength=8, c_max_m_s=343.0, shape=(20, 18, 16), dtype="float64", kind="3d"
        )
        src = PointSources(
            cells=np.array([[9, 8, 7]]), signal=ToneBurst(50e3, 2.0), weights=jnp.ones(1), lags_s=jnp.zeros(1)
        )
        return Stepper.build(g, Medium(343.0, 1.2), src, Sensors(), Edges(z_lo="rigid", thickness_cells=4))
    kind = "rz" if case.startswith("rz") else "2d"
    g = make_grid(
        frequency_hz=50e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(40, 34), dtype="float64", kind=kind
    )
    x = np.arange(40.0)[:, None] * np.ones((1, 34))
    soft = PointSources(
        cells=np.array([[14, j] for j in range(3)] if kind == "rz" else [[14, 15], [14, 16]]),
        signal=ToneBurst(50e3, 2.0),
        weights=jnp.linspace(0.8, 1.2, 3 if kind == "rz" else 2),
        lags_s=jnp.zeros(3 if kind == "rz" else 2),
    )
    if case == "rz":
        edges = Edges.axisymmetric("rigid", "pml", "pml", thickness_cells=6)
        return Stepper.build(g, Medium(343.0, jnp.where(x > 26, 2.0, 1.2)), soft, Sensors(), edges)
    hard = PointSources(
        cells=np.array([[20, 20]]),
        signal=ToneBurst(50e3, 2.0),
        weights=jnp.ones(1),
        lags_s=jnp.zeros(1),
        injection="hard",
    )
    rigid = ((x > 24) & (x < 27)).astype(float) * (np.arange(34)[None, :] > 12)
    medium = Medium(343.0, jnp.where(x > 30, 2.0, 1.2), rigid=jnp.asarray(rigid), absorption_db_per_m=3.0)
    return Stepper.build(g, medium, (soft, hard), Sensors(), Edges(y_lo="rigid", thickness_cells=6))


@pytest.mark.parametrize("case", ["2d", "rz", "3d"])
def test_layered_state_equals_the_split_field_form_on_every_cell(case):
    """Obstacles, a density step, viscous absorption, soft and hard sources, a rigid side (2-D);
    the rz r_hi layer's ring correction; the 3-D layer with its z boxes: float64 rounding."""
    stepper = _scene(case)
    n = 90 if case != "3d" else 40
    ref = np.asarray(_full_split_field(stepper, n))
    got = np.asarray(_layered(stepper, n))
    peak = np.abs(ref).max()
    assert peak > 1e-3
    np.testing.assert_allclose(got, ref, rtol=0, atol=n * 16 * np.finfo(float).eps * peak)
    st = stepper.init()
    assert isinstance(st, StaggeredState)
    n_layer = sum(int(np.prod(f.parts[0].shape)) for f in st.layers)
    n_damped = len(np.flatnonzero(_sigma_cells(stepper)))
    assert n_layer == n_damped < np.prod(stepper.grid.shape)  # the split fields live on the layer only


def test_interior_is_the_lossless_leapfrog_bit_for_bit():
    """Soft window sides (zero ghosts, no face masks) against PML sides: the same interior
    arithmetic, so the fields are equal to the last bit until the wave reaches the layer."""
    g = make_grid(frequency_hz=50e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(64, 60), dtype="float32")
    src = PointSources(
        cells=np.array([[32, 30]]), signal=ToneBurst(50e3, 2.0), weights=jnp.ones(1), lags_s=jnp.zeros(1)
    )
    sens = Sensors(probes=np.array([[40, 30]]))
    leap = Stepper.build(g, Medium(343.0, 1.2), src, sens, Edges.all("soft"))
    layered = Stepper.build(g, Medium(343.0, 1.2), src, sens, Edges(thickness_cells=8))
    n = 20  # the stencil reaches one cell a step: 30 - 20 > 8 cells of layer
    a = run(leap, n, backend="jax")
    b = run(layered, n, backend="jax")
    assert float(jnp.abs(a.final.pressure).max()) > 0
    np.testing.assert_array_equal(np.asarray(a.final.pressure), np.asarray(b.final.pressure))
    np.testing.assert_array_equal(np.asarray(a.probes), np.asarray(b.probes))


@pytest.mark.parametrize(
    "shape,edges",
    [
        ((30, 26), Edges(thickness_cells=5)),
        ((30, 26), Edges(x_lo="rigid", y_hi="soft", thickness_cells=5)),
        ((30, 26), Edges.axisymmetric("pml", "rigid", "pml", thickness_cells=5)),
        ((9, 1), Edges(y_lo="rigid", y_hi="rigid", thickness_cells=6)),  # layers meeting in a thin grid
        ((12, 11, 10), Edges(y_lo="rigid", thickness_cells=3)),
    ],
)
def test_layer_boxes_cover_exactly_the_damped_cells(shape, edges):
    boxes = layer_boxes(shape, edges.for_rank(len(shape)))
    count = np.zeros(shape, int)
    for box in boxes:
        count[tuple(slice(lo, hi) for lo, hi in box)] += 1
    assert count.max() <= 1  # disjoint
    damped = np.zeros(shape, bool)  # a cell with sigma > 0 on itself or one of its faces
    for axis, n in enumerate(shape):
        key = "xyz"[axis]
        e = edges.for_rank(len(shape))
        if getattr(e, f"{key}_lo") not in ("pml",) and getattr(e, f"{key}_hi") not in ("pml",):
            continue
        pml_only = Edges(
            **{
                **{s: "rigid" for s in e.sides_for(len(shape))},
                f"{key}_lo": getattr(e, f"{key}_lo"),
                f"{key}_hi": getattr(e, f"{key}_hi"),
            },
            thickness_cells=e.thickness_cells,
        )
        cell = pml_only.layer_depth(n, f"{key}_lo", f"{key}_hi", faces=False) > 0
        face = pml_only.layer_depth(n, f"{key}_lo", f"{key}_hi", faces=True) > 0
        hit = cell | face[:-1] | face[1:]
        damped |= hit.reshape(tuple(-1 if a == axis else 1 for a in range(len(shape))))
    np.testing.assert_array_equal(count == 1, damped)


def test_oblique_reflection_is_kept():
    """A point source 4 wavelengths inside a 20-cell layer (20 cells per wavelength, float64):
    the wave meets the layer at 45 deg at the window's corner probe. The split-field form on every
    cell gave -117.5 dB there and -123.3 dB on the axis (benchmarks/pml_reflection.py, before the
    layered state); the same scheme must stay in that class: below -110 dB."""
    from difflattice.apps.accuracy_wall import edge_sweep

    sweep = edge_sweep(cells_per_wavelength=(20,), thicknesses_cells=(20,), dtype="float64", kinds=("pml",))
    row = next(r for r in sweep["rows"] if r["edge"] == "pml")
    assert row["reflection_db_corner"] < -110.0
    assert row["reflection_db_axis"] < -115.0


def test_fractional_speed_zero_walls_do_not_depend_on_the_edges():
    """Causality: until the wave reaches the window's edges, what the edges are cannot matter. A
    fractional (smoothly rasterised) speed-zero wall near a point source, PML edges against rigid
    ones, probes by the wall, 60 steps (the wave travels ~42 cells; the PML starts 58 away): equal
    to rounding (float64, bound n_steps x 16 eps x peak). The whole-grid split-field form of
    earlier versions failed this (26 % of the peak at a probe by the wall): it applied the cells'
    `keep` (1 - occupancy) to the split parts, which is not the leapfrog's arithmetic."""
    g = make_grid(frequency_hz=50e3, cells_per_wavelength=8, c_max_m_s=343.0, shape=(160, 140), dtype="float64")
    occ = np.zeros((160, 140))
    occ[100:104, 40:100] = 0.5
    med = Medium(343.0, 1.2, soft=jnp.asarray(occ), boundary_model="speed_zero")
    src = PointSources(
        cells=[(80, 70)], signal=ToneBurst(50e3, 2), weights=jnp.ones(1), lags_s=jnp.zeros(1), injection="soft"
    )
    sens = Sensors(probes=[(95, 70), (106, 70), (102, 60)])
    n = 60
    a = run(Stepper.build(g, med, (src,), sens, Edges(thickness_cells=12)), n, backend="jax").probes
    b = run(Stepper.build(g, med, (src,), sens, Edges.all("rigid")), n, backend="jax").probes
    peak = float(jnp.abs(b).max())
    assert peak > 1e-3
    assert float(jnp.abs(a - b).max()) <= n * 16 * np.finfo(np.float64).eps * peak


def _uniform_pml(stencil: str, shape, thickness: int = 5) -> Stepper:
    kind = "3d" if len(shape) == 3 else "2d"
    g = make_grid(
        frequency_hz=50e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=shape, dtype="float64", kind=kind,
        stencil=stencil,
    )  # fmt: skip
    centre = [[s // 2 for s in shape]]
    src = PointSources(cells=np.array(centre), signal=ToneBurst(50e3, 2.0), weights=jnp.ones(1), lags_s=jnp.zeros(1))
    return Stepper.build(g, Medium(343.0, 1.2), src, Sensors(), Edges.all("pml", thickness_cells=thickness))


@pytest.mark.parametrize(
    ("stencil", "shape"), [("wide", (30, 27, 24)), ("isotropic", (30, 27, 24)), ("isotropic", (40, 34))]
)
def test_isotropic_and_wide_layers_take_their_face_values_from_the_box(stencil, shape):
    """The isotropic and wide stencils' layer face values from each box and a two-cell halo
    (`stepper._box_face_values`) are the whole grid's (`operators.face_gradient`, sliced): the same
    arithmetic on the same values, so equal to rounding (<= 16 eps max|q|: a face value sums at
    most ~10 terms of size <= 4 max|q|, each rounded once)."""
    from difflattice.solver import stepper as stepper_mod

    st = _uniform_pml(stencil, shape)
    lat = st.lattice
    q = jnp.asarray(np.random.default_rng(4).standard_normal(shape))
    assert stepper_mod._local_face_values(lat, q.shape, q.dtype)
    full = [np.asarray(face_gradient(lat, q, a)) for a in range(q.ndim)]
    tol = 16 * np.finfo(float).eps * float(jnp.max(jnp.abs(q)))
    for box in lat.pml.boxes:
        got = stepper_mod._box_face_values(lat, q, box)
        for a, g in enumerate(got):
            want = full[a][tuple(slice(lo, hi + 1) if i == a else slice(lo, hi) for i, (lo, hi) in enumerate(box))]
            assert g.shape == want.shape
            np.testing.assert_allclose(np.asarray(g), want, rtol=0, atol=tol)


def test_box_face_values_run_equals_the_whole_grid_form(monkeypatch):
    """A 3-D wide-stencil PML scene stepped with the box-local face values and with the whole
    grid's: float64 rounding (the file's criterion, n_steps * 16 eps * peak)."""
    from difflattice.solver import stepper as stepper_mod

    st = _uniform_pml("wide", (30, 27, 24))
    n = 40
    local = np.asarray(run(st, n).final.pressure)
    monkeypatch.setattr(stepper_mod, "_local_face_values", lambda *a: False)
    whole = np.asarray(run(st, n, backend="jax").final.pressure)
    peak = np.abs(whole).max()
    assert peak > 1e-6
    np.testing.assert_allclose(local, whole, rtol=0, atol=n * 16 * np.finfo(float).eps * peak)


def test_a_rigid_side_keeps_the_whole_grid_face_values():
    from difflattice.solver import stepper as stepper_mod

    g = make_grid(
        frequency_hz=50e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(30, 27, 24), dtype="float64", kind="3d",
        stencil="wide",
    )  # fmt: skip
    st = Stepper.build(g, Medium(343.0, 1.2), (), Sensors(), Edges(z_lo="rigid", thickness_cells=5))
    assert not stepper_mod._local_face_values(st.lattice, tuple(g.shape), jnp.float64)
