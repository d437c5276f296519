"""Air's absorption in the time domain (`AirConditions` on a `Medium`, `coefficients.AirRelaxation`):
a plane wave's measured attenuation against ISO 9613-1 and its phase speed against the lattice's
own dispersion relation, the discrete energy's exact decay (and never growth over 1e5 steps at
the absorbing limit), lossless scenes carrying no memory fields, refusals, the adjoint
declining by name, and gradients w.r.t. temperature and humidity against central differences."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from difflattice import air
from difflattice.apps.accuracy_air import plane_wave
from difflattice.lattice import Edges
from difflattice.lattice.coefficients import absorbing_courant
from difflattice.lattice.grid import make_grid
from difflattice.lattice.medium import AirConditions, Medium
from difflattice.lattice.operators import operator
from difflattice.solver import LeapfrogState, Sensors, Stepper, run
from difflattice.solver.sources import PointSources, ToneBurst


def test_plane_wave_attenuation_and_phase_speed():
    """40 kHz, 20 deg C, 50 % RH at 20 cells per wavelength: the attenuation measured from the
    amplitudes at two ranges 60 wavelengths apart is ISO's within 5 % (the issue's target; the
    lattice's own dispersion moves it by ~k^2/24 ~ 0.5 %) and the step's dispersion relation's
    within 1e-4 (phasor fit and PML reflections ~1e-5 of the 0.05 Np span); the phase speed is
    the dispersion relation's within 1e-6 (0.05 % is the issue's target)."""
    r = plane_wave(40e3, 20.0, 50.0)
    assert r.alpha_db_per_m_lattice == pytest.approx(r.alpha_db_per_m_iso, rel=0.05)
    assert r.alpha_db_per_m_lattice == pytest.approx(r.alpha_db_per_m_lattice_model, rel=1e-4)
    assert r.phase_speed_m_s_lattice == pytest.approx(r.phase_speed_m_s_model, rel=1e-6)


def _box(n=12, margin=1.0, seed=0):
    t, h = 20.0, 50.0
    cond = AirConditions(t, h)
    c0 = air.speed_of_sound_m_s(t, h)
    f, cpw = 200e3, 8.0  # coarse and high: the largest eta and theta_O of the study's grid
    courant = absorbing_courant(f, cpw, c0, cond, margin=margin)
    grid = make_grid(
        frequency_hz=f, cells_per_wavelength=cpw, c_max_m_s=c0, shape=(n, n), courant=courant, dtype="float64"
    )
    stepper = Stepper.build(grid, cond.medium(), edges=Edges.all("rigid"))
    rng = np.random.default_rng(seed)
    p0 = jnp.asarray(rng.standard_normal((n, n)))  # every mode, the checkerboard included
    # at rest (p_prev = p): a uniform dp/dt would drift without bound in a closed box, A's null mode
    st = eqx.tree_at(lambda s: (s.p, s.p_prev), stepper.init(), (p0, p0))
    return stepper, st


def _energy_and_loss(stepper, before, after):
    """E(n+1/2) of the absorbing step (docs/air.md) from the state before and after a step, and the
    step's predicted loss terms that need Q(n) (the eta term needs v(n-1/2) too: returned apart)."""
    lat, r = stepper.lattice, stepper.lattice.relax
    ip = lambda x, y: -jnp.sum(x * operator(lat, y))  # c^2 <x, A y>
    v = after.p - after.p_prev
    avg = 0.5 * (after.p + after.p_prev)
    e = 0.5 * jnp.sum(v * v) - (1 + 2 * r.eta) / 8 * ip(v, v) + 0.5 * ip(avg, avg)
    for eps, a, g, q in zip(r.eps, r.a, r.g, before.relax_q):
        e = e + eps / (2 * g) * ((1 + a) / 2 * ip(q, q) + g * ip(v, q))
    return e


def test_discrete_energy_decays_exactly_as_derived():
    """Per step E changes by -(c^2 eta / 4)|v+ + v-|_A^2 - sum (c^2 eps (1 - a) / (4 g))|Q(n) + Q(n-1)|_A^2,
    to round-off (float64), from a random field at the absorbing limit."""
    stepper, st = _box()
    lat, r = stepper.lattice, stepper.lattice.relax
    ip = lambda x, y: -jnp.sum(x * operator(lat, y))
    states = [st]
    for _ in range(4):
        states.append(stepper.step(states[-1])[0])
    for n in (2, 3):
        s0, s1, s2 = states[n - 1], states[n], states[n + 1]
        de = _energy_and_loss(stepper, s1, s2) - _energy_and_loss(stepper, s0, s1)
        vv = (s2.p - s2.p_prev) + (s1.p - s1.p_prev)
        loss = r.eta / 4 * ip(vv, vv)
        for eps, a, g, q1, q0 in zip(r.eps, r.a, r.g, s1.relax_q, s0.relax_q):
            loss = loss + eps * (1 - a) / (4 * g) * ip(q1 + q0, q1 + q0)
        scale = float(_energy_and_loss(stepper, s0, s1))
        assert float(loss) > 0
        assert float(de) == pytest.approx(-float(loss), abs=1e-12 * scale)


def test_energy_never_grows_over_1e5_steps_at_the_absorbing_limit():
    stepper, st = _box(margin=1.0)

    def body(carry, _):
        s, e_prev = carry
        s2, _ = stepper.step(s)
        e = _energy_and_loss(stepper, s, s2)
        return (s2, e), e - e_prev

    s1, _ = stepper.step(st)
    e1 = _energy_and_loss(stepper, st, s1)
    (final, e_last), de = jax.jit(lambda s, e: jax.lax.scan(body, (s, e), None, length=100_000))(s1, e1)
    de = np.asarray(de)
    assert float(e_last) > 0 and float(e_last) < float(e1)
    assert de.max() <= 1e-13 * float(e1)  # never grows beyond round-off
    assert np.isfinite(np.asarray(final.p)).all() and float(jnp.abs(final.p).max()) < 10


def test_lossless_limit_is_not_enough_with_absorption():
    """At the lossless limit (0.99999 of 1/sqrt(2)) the absorbing step's stiffening (x1.00225 in c^2
    here) pushes the checkerboard of a 64 x 64 box (rho(A) = 8 sin^2(63 pi / 128), 0.06 % under 8)
    over the edge: it grows. So the lowered limit is needed, not an artefact of the bound."""
    stepper, st = _box(n=64)
    lossless_limit_c = 0.99999 / np.sqrt(2)
    scale = (lossless_limit_c / float(stepper.lattice.c)) ** 2
    over = eqx.tree_at(lambda s: s.lattice.K, stepper, stepper.lattice.K * scale)
    final = jax.jit(lambda s: jax.lax.scan(lambda c, _: (over.step(c)[0], None), s, None, length=3000)[0])(st)
    assert float(jnp.abs(final.p).max()) > 1e3 * float(jnp.abs(st.p).max())
    # control: the same K without the absorption's terms stays bounded
    lossless = eqx.tree_at(lambda s: s.lattice.relax, over, None, is_leaf=lambda x: x is None)
    plain = eqx.tree_at(lambda s: s.relax_q, st, None, is_leaf=lambda x: x is None)
    ok = jax.jit(lambda s: jax.lax.scan(lambda c, _: (lossless.step(c)[0], None), s, None, length=3000)[0])(plain)
    assert float(jnp.abs(ok.p).max()) < 10 * float(jnp.abs(st.p).max())


def test_absorbing_limit_is_refused_with_the_fix():
    cond = AirConditions(20.0, 50.0)
    c0 = air.speed_of_sound_m_s(20.0, 50.0)
    grid = make_grid(frequency_hz=200e3, cells_per_wavelength=8, c_max_m_s=c0, shape=(16, 16), dtype="float64")
    with pytest.raises(ValueError, match="lower grid.courant to <="):
        Stepper.build(grid, cond.medium(), edges=Edges.all("rigid"))
    with pytest.raises(ValueError, match="not both"):
        Medium(343.0, 1.2, absorption_db_per_m=1.0, air=cond)


def test_lossless_scene_carries_and_computes_nothing_of_it():
    """No `air`: no relaxation coefficients, no memory fields in the state, and the compiled step
    is the lossless one (fewer equations than the absorbing step, no exp/expm1 and no extra inputs)."""
    grid = make_grid(frequency_hz=40e3, cells_per_wavelength=12, c_max_m_s=343.0, shape=(24, 24), courant=0.6)
    lossless = Stepper.build(grid, Medium(343.0, 1.2), edges=Edges.all("rigid"))
    absorbing = Stepper.build(grid, AirConditions(20.0, 50.0).medium(), edges=Edges.all("rigid"))
    s0 = lossless.init()
    assert lossless.lattice.relax is None and s0.relax_q is None
    assert len(jax.tree_util.tree_leaves(s0)) == 3  # n, p, p_prev
    assert len(jax.tree_util.tree_leaves(absorbing.init())) == 5  # + two memory fields
    n_lossless = len(jax.make_jaxpr(lambda s: lossless.step(s))(s0).jaxpr.eqns)
    n_abs = len(jax.make_jaxpr(lambda s: absorbing.step(s))(absorbing.init()).jaxpr.eqns)
    assert n_abs > n_lossless
    stag = Stepper.build(grid, Medium(343.0, 1.2), edges=Edges(thickness_cells=4))
    assert stag.init().relax_q is None  # (P(n-1) is the leapfrog's own field now)


def test_adjoint_declines_by_name_and_native_runs():
    """The hand-written adjoint declines air absorption by name (`adjoint="auto"` falls back); the
    native kernels run it (their equality with the JAX loop: tests/core/test_air_native.py)."""
    from difflattice.solver import adjoint
    from difflattice.solver.native.kernels import unsupported

    grid = make_grid(frequency_hz=40e3, cells_per_wavelength=12, c_max_m_s=343.0, shape=(24, 24), courant=0.6)
    st = Stepper.build(grid, AirConditions(20.0, 50.0).medium(), edges=Edges.all("rigid"))
    assert unsupported(st, None, None) is None
    assert "air absorption" in adjoint.supports(st)
    res = run(st, 5, backend="auto")
    assert isinstance(res.final, LeapfrogState) and res.final.relax_q is not None


def _probe_energy(t_c, rh, grid, src, sens, edges):
    cond = AirConditions(t_c, rh)
    stepper = Stepper.build(grid, cond.medium(), src, sens, edges)
    p = run(stepper, 420, backend="jax").probes
    return jnp.sum(p * p)


def test_gradients_wrt_temperature_and_humidity_match_central_differences():
    """A 200 kHz burst along a strip (the absorption is strong there): d/dT and d/dRH of the
    received energy by reverse mode agree with central differences (step 1e-3 deg C / %: the
    truncation error ~ h^2 f''' is < 1e-6 relative, the rounding ~1e-16 / 1e-3 * 10)."""
    c_max = air.speed_of_sound_m_s(40.0, 90.0)  # the grid is sized for the fastest air tried
    grid = make_grid(
        frequency_hz=200e3, cells_per_wavelength=10, c_max_m_s=c_max, shape=(500, 1), courant=0.69, dtype="float64"
    )
    edges = Edges(x_lo="pml", x_hi="pml", y_lo="rigid", y_hi="rigid", thickness_cells=20)
    src = PointSources(cells=[(40, 0)], signal=ToneBurst(200e3, 4), weights=jnp.ones(1), lags_s=jnp.zeros(1))
    sens = Sensors(probes=np.array([[400, 0]]))
    fn = lambda t, h: _probe_energy(t, h, grid, src, sens, edges)
    t0, h0 = jnp.asarray(20.0), jnp.asarray(50.0)
    gt, gh = jax.grad(fn, argnums=(0, 1))(t0, h0)
    d = 1e-3
    fd_t = (fn(t0 + d, h0) - fn(t0 - d, h0)) / (2 * d)
    fd_h = (fn(t0, h0 + d) - fn(t0, h0 - d)) / (2 * d)
    assert abs(float(gh)) > 0 and abs(float(gt)) > 0
    assert float(gh) == pytest.approx(float(fd_h), rel=1e-5)
    assert float(gt) == pytest.approx(float(fd_t), rel=1e-5)


def test_accuracy_air_writes_rows_table_and_plot(tmp_path):
    import json

    from difflattice.apps import accuracy_air

    rows = accuracy_air.sweep((12.0,), (80e3,), (10.0,), (30.0,), quick=True)
    accuracy_air.write(rows, tmp_path)
    data = json.loads((tmp_path / "accuracy_air.json").read_text())
    keys = {"frequency_hz", "temperature_c", "humidity_pct", "pressure_pa", "alpha_db_per_m_lattice"}
    keys |= {"alpha_db_per_m_iso", "phase_speed_m_s_lattice", "phase_speed_m_s_model"}
    assert len(data) == 1 and keys <= set(data[0])
    assert abs(data[0]["alpha_db_per_m_lattice"] / data[0]["alpha_db_per_m_iso"] - 1) < 0.05
    assert (tmp_path / "accuracy_air.png").stat().st_size > 0
    assert "| 12 | 80 | 10 | 30 |" in (tmp_path / "accuracy_air_table.md").read_text()


def test_three_d_and_rz_steps_carry_the_absorption():
    """The step is shape-agnostic: a 3-D split-field (PML) run and an rz leapfrog run carry the two
    memory fields and lose energy that the lossless twin keeps."""
    cond = AirConditions(20.0, 50.0)
    c0 = air.speed_of_sound_m_s(20.0, 50.0)
    for kind, shape, edges, courant in (
        ("3d", (14, 14, 14), Edges(thickness_cells=4), 0.5),
        ("rz", (24, 16), Edges.axisymmetric(z_lo="rigid", z_hi="rigid", r_hi="rigid"), 0.65),
    ):
        grid = make_grid(
            frequency_hz=200e3,
            cells_per_wavelength=6,
            c_max_m_s=c0,
            shape=shape,
            courant=courant,
            dtype="float64",
            kind=kind,
        )
        centre = np.array([[n // 2 for n in shape]])
        if kind == "rz":
            centre[0, 1] = 0
        src = PointSources(cells=centre, signal=ToneBurst(200e3, 2), weights=jnp.ones(1), lags_s=jnp.zeros(1))
        out = {}
        for name, med in (("abs", cond.medium()), ("loss", Medium(c0, air.density_kg_m3(20.0, 101325.0, 50.0)))):
            st = Stepper.build(grid, med, src, Sensors(), edges)
            final = run(st, 60, backend="jax").final
            out[name] = final
        assert out["abs"].relax_q is not None and len(out["abs"].relax_q) == 2
        assert out["loss"].relax_q is None
        pa, pl = (np.asarray(out[k].pressure) for k in ("abs", "loss"))
        assert np.isfinite(pa).all() and 0 < np.linalg.norm(pa) < np.linalg.norm(pl)
