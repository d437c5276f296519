"""A grid split across two devices with JAX's own sharding gives the single-device numbers.

Runs in a subprocess because the host device count must be set before JAX starts.
"""

import os
import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent(
    """
    import jax, jax.numpy as jnp, numpy as np
    jax.config.update("jax_enable_x64", True)
    assert len(jax.devices()) == 2, jax.devices()
    from difflattice.lattice.grid import make_grid
    from difflattice.lattice import Edges
    from difflattice.lattice.medium import Medium
    from difflattice.solver.sensors import Sensors
    from difflattice.solver import simulate, grid_sharding
    from difflattice.solver.sources import line_transducer, ToneBurst

    g = make_grid(frequency_hz=50e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(96, 70), dtype="float64")
    x = jnp.arange(96.0)[:, None] * jnp.ones((1, 70))
    for edges in (Edges(thickness_cells=10), Edges.all("rigid")):
        med = Medium(jnp.where(x > 60, 300.0, 343.0), jnp.where(x > 60, 2.0, 1.2), rigid=(x > 80).astype(jnp.float64))
        src = line_transducer(g, (30 * g.dx_m, 35 * g.dx_m), n_cells=9, signal=ToneBurst(50e3, 3))
        sens = Sensors(probes=[(50, 35), (70, 20)], p_max=True, phasor_cells=[(55, 30), (45, 40)])
        a = simulate(g, med, src, sens, n_steps=150, edges=edges)
        b = simulate(g, med, src, sens, n_steps=150, edges=edges, sharding=grid_sharding())
        assert len(b.final.pressure.sharding.device_set) == 2, b.final.pressure.sharding
        scale = float(jnp.abs(a.probes).max())
        assert scale > 1e-3
        for u, v in ((a.probes, b.probes), (a.p_max, b.p_max), (a.phasors, b.phasors), (a.final.pressure, b.final.pressure)):
            err = float(jnp.abs(u - v).max())
            assert err <= 1e-12 * scale, err
    print("OK")
    """
)


def test_two_device_sharding_matches_one_device():
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2", JAX_PLATFORMS="cpu")
    r = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0 and "OK" in r.stdout, r.stderr[-3000:]
