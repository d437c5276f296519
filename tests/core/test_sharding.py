"""A grid split across two devices with JAX's own sharding gives the single-device numbers
(2-D: media, a rigid obstacle, PML and rigid edges). Harness: `tests/two_devices.py`."""

from two_devices import assert_two_devices_match

SCENE = """
from difflattice.lattice.grid import make_grid
from difflattice.lattice import Edges
from difflattice.lattice.medium import Medium
from difflattice.solver.sensors import Sensors
from difflattice.solver import simulate, grid_sharding
from difflattice.solver.sources import line_transducer, ToneBurst

def cases():
    g = make_grid(frequency_hz=50e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(96, 70), dtype="float64")
    x = jnp.arange(96.0)[:, None] * jnp.ones((1, 70))
    for edges in (Edges(thickness_cells=10), Edges.all("rigid")):
        med = Medium(jnp.where(x > 60, 300.0, 343.0), jnp.where(x > 60, 2.0, 1.2), rigid=(x > 80).astype(jnp.float64))
        src = line_transducer(g, (30 * g.dx_m, 35 * g.dx_m), n_cells=9, signal=ToneBurst(50e3, 3))
        sens = Sensors(probes=[(50, 35), (70, 20)], p_max=True, phasor_cells=[(55, 30), (45, 40)])
        yield (
            simulate(g, med, src, sens, n_steps=150, edges=edges),
            simulate(g, med, src, sens, n_steps=150, edges=edges, sharding=grid_sharding()),
        )
"""


def test_two_device_sharding_matches_one_device():
    assert_two_devices_match(SCENE)
