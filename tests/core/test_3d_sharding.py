"""A 3-D grid split across two devices (along x) gives the single-device numbers, for the
leapfrog (rigid edges) and the split-field PML, with cut-cell obstacles and a disc transducer.
Runs in a subprocess because the host device count must be set before JAX starts."""

import os
import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent(
    """
    import jax, jax.numpy as jnp, numpy as np
    jax.config.update("jax_enable_x64", True)
    assert len(jax.devices()) == 2, jax.devices()
    from difflattice.lattice import Edges, Medium
    from difflattice.lattice.geometry3d import Sphere, rasterise3d
    from difflattice.lattice.grid import make_grid
    from difflattice.solver import Sensors, ToneBurst, grid_sharding, simulate
    from difflattice.solver.sources import disc_transducer_3d

    g = make_grid(frequency_hz=40e3, cells_per_wavelength=8, c_max_m_s=343.0, shape=(40, 30, 28), kind="3d",
                  dtype="float64")
    med = Medium(343.0, 1.2, rigid=rasterise3d(Sphere(jnp.array([28.0, 15.3, 14.2]) * g.dx_m, jnp.asarray(4.4 * g.dx_m)), g))
    src = disc_transducer_3d(g, (12 * g.dx_m, 15 * g.dx_m, 14 * g.dx_m), (1, 0, 0), diameter_m=6 * g.dx_m,
                          signal=ToneBurst(40e3, 2))
    sens = Sensors(probes=[(20, 15, 14), (30, 8, 20)], p_max=True, phasor_cells=[(22, 12, 10), (18, 20, 16)])
    for edges in (Edges.all("pml", thickness_cells=6), Edges.all("rigid")):
        a = simulate(g, med, src, sens, n_steps=80, edges=edges)
        b = simulate(g, med, src, sens, n_steps=80, edges=edges, sharding=grid_sharding(ndim=3))
        assert len(b.final.pressure.sharding.device_set) == 2, b.final.pressure.sharding
        scale = float(jnp.abs(a.probes).max())
        assert scale > 1e-4, scale
        for u, v in ((a.probes, b.probes), (a.p_max, b.p_max), (a.phasors, b.phasors), (a.final.pressure, b.final.pressure)):
            err = float(jnp.abs(u - v).max())
            assert err <= 1e-12 * scale, err
    print("OK")
    """
)


def test_two_device_sharding_matches_one_device_in_3d():
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2", JAX_PLATFORMS="cpu")
    r = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0 and "OK" in r.stdout, r.stderr[-3000:]
