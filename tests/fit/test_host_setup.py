"""Host-side set-up compiles no per-operation XLA programs (issue 15, fit start-up).

Outside a program, every `jnp` operation on host values (and `jnp.asarray` of a NumPy array)
compiles a one-operation program per new shape; a fresh process pays ~10 ms for each, which
added up to ~135 programs per fit. These tests count the backend compilations JAX reports
(`jax.monitoring`) around the host-side steps, and check that the NumPy paths give the same
numbers as the JAX ones.
"""

import contextlib

import jax
import jax.numpy as jnp
import numpy as np

from difflattice.fit import solve
from difflattice.fit.model import ModelSpec, device_array
from difflattice.fit.problem import build_problem, initial_params
from difflattice.fit.solve import FitOptions
from difflattice.fit.transfer import Transfer
from difflattice.lattice.grid import make_grid
from difflattice.observe.farfield import BoxContour, field_at
from difflattice.observe.farfield_rz import CylinderSurface, far_field_rz, field_at_rz

COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"


@contextlib.contextmanager
def count_compiles():
    n = [0]

    def listener(event, duration_secs, **kwargs):
        if event == COMPILE_EVENT:
            n[0] += 1

    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        yield n
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)


def test_device_array_is_a_plain_transfer():
    # shapes no other test uses, so a compile would be new here
    with count_compiles() as n:
        a = device_array(np.arange(7.0, dtype=np.float32).reshape(1, 7))
        b = device_array(0.25)
    assert n[0] == 0
    assert isinstance(a, jax.Array) and a.dtype == jnp.float32 and a.shape == (1, 7)
    assert not b.weak_type and float(b) == 0.25
    assert device_array(a) is a  # a JAX array passes through


def test_far_field_of_host_phasors_is_numpy_and_equals_the_jax_path():
    grid = make_grid(frequency_hz=40e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=(61, 61))
    contour = BoxContour(25, 35, 25, 35)
    m2 = len(contour.cells)
    rng = np.random.default_rng(3)
    ph = rng.normal(size=m2) + 1j * rng.normal(size=m2)
    pts = np.stack([30 + 900 * np.cos(np.linspace(-1, 1, 13)), 30 + 900 * np.sin(np.linspace(-1, 1, 13))], 1)
    with count_compiles() as n:
        host = field_at(ph, contour, grid, pts, dispersion="continuum")
    assert n[0] == 0
    assert isinstance(host, np.ndarray)
    dev = np.asarray(field_at(jnp.asarray(ph), contour, grid, pts, dispersion="continuum"))
    # same products summed in another order: complex128 round-off
    np.testing.assert_allclose(host, dev, rtol=1e-12, atol=1e-12 * np.abs(dev).max())


def test_rz_far_fields_of_host_phasors_are_numpy_and_equal_the_jax_path():
    grid = make_grid(frequency_hz=40e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=(60, 40), kind="rz")
    surf = CylinderSurface(5, 25, 17)
    m2 = len(surf.cells)
    rng = np.random.default_rng(5)
    ph = rng.normal(size=m2) + 1j * rng.normal(size=m2)
    pts = np.stack([15 + 400 * np.cos(np.linspace(0.1, 1.4, 7)), 400 * np.sin(np.linspace(0.1, 1.4, 7))], 1)
    angles = np.linspace(0.0, 80.0, 9)
    with count_compiles() as n:
        near = field_at_rz(ph, surf, grid, pts)
        far = far_field_rz(ph, surf, grid, angles)
    assert n[0] == 0
    assert isinstance(near, np.ndarray) and isinstance(far, np.ndarray)
    for host, dev in (
        (near, field_at_rz(jnp.asarray(ph), surf, grid, pts)),
        (far, far_field_rz(jnp.asarray(ph), surf, grid, angles)),
    ):
        np.testing.assert_allclose(host, np.asarray(dev), rtol=1e-12, atol=1e-12 * np.abs(np.asarray(dev)).max())


def _synthetic_problem(n_cells: int, n_ang: int, n_wave: int, seed: int = 0):
    """A line-model problem on random transfers (shapes chosen per test, so its compilations are
    new there), the data those transfers give for a uniform face."""
    rng = np.random.default_rng(seed)
    grid = make_grid(frequency_hz=40e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=(3, 3))
    spec = ModelSpec(n_cells=n_cells, dx_m=grid.dx_m, frequency_hz=40e3, n_basis=2)
    lobe_T = rng.normal(size=(n_ang, n_cells)) + 1j * rng.normal(size=(n_ang, n_cells))
    wave_T = rng.normal(size=(n_wave, n_cells)) + 1j * rng.normal(size=(n_wave, n_cells))
    tr = Transfer(grid=grid, n_cells=n_cells, cell_offset_m=spec.y_m, lobe=lobe_T, wave=wave_T)

    class Lobe:
        level_db = 20 * np.log10(np.abs(lobe_T.sum(1)))
        sigma_db = np.full(n_ang, 0.3)

    class Wave:
        phase_rad = -np.angle(wave_T.sum(1))
        sigma_rad = np.full(n_wave, 0.01)

    return build_problem(spec, tr, Lobe(), Wave(), FitOptions())  # type: ignore[arg-type]


def test_initial_parameters_compile_whole_functions_only():
    """The diameter scan and the closed-form offsets: 25 diameters x (cost, lobe and wave model)
    evaluated through two jitted functions (`_cost`, `_models`), i.e. at most a handful of
    programs for one model structure (op-by-op evaluation compiled ~40)."""
    problem = _synthetic_problem(23, 41, 17)  # shapes of no other test
    with count_compiles() as n:
        p0 = initial_params(problem)
    assert n[0] <= 4, f"{n[0]} programs compiled for the initial parameters"
    assert set(p0.names()) == {"gain_db", "phase0", "w", "lag", "diam"}
    assert all(np.isfinite(np.asarray(v)).all() for v in jax.tree_util.tree_leaves(p0))


def test_the_fit_stages_share_one_set_of_solver_programs(monkeypatch):
    """The first stage holds the profiles (`hold`: data, not structure), so the second and third
    stages reuse its compiled `init` and `step` (before: a second structure, traced and compiled
    again in every process, 0.24 s); the held parameters come back exactly as they went in."""
    problem = _synthetic_problem(19, 37, 13, seed=1)  # shapes of no other test
    p0 = initial_params(problem)
    runs = []
    real = solve._run_stage

    def counted(*args, **kwargs):
        with count_compiles() as n:
            st = real(*args, **kwargs)
        runs.append((kwargs["stage"], n[0], st))
        return st

    monkeypatch.setattr(solve, "_run_stage", counted)
    solve._fit_stages(problem, p0, FitOptions(), True, None)
    assert [r[0] for r in runs] == [1, 2, 3]
    assert runs[0][1] >= 2, "the first stage compiles the solver's init and step"
    assert runs[1][1] == 0 and runs[2][1] == 0, f"later stages compiled {runs[1][1]} and {runs[2][1]} programs"
    s1 = runs[0][2]
    for k in ("w", "lag"):
        np.testing.assert_array_equal(np.asarray(getattr(s1.y, k)), np.asarray(getattr(p0, k)))
    assert s1.n_accepted > 0 and float(s1.y.diam) != float(p0.diam)  # the free ones moved
