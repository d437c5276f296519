"""A grid split across two devices with JAX's own sharding gives the single-device numbers, on
every lattice kind (the physics and the harness are the same; the scenes differ by what each kind
has): 2-D with media, a rigid obstacle, PML and rigid edges; rz with a disc, the cylindrical PML
and rigid edges; 3-D with cut-cell obstacles, a disc transducer, the split-field PML and the
leapfrog, with the 7-point, the 19-point isotropic and the 25-point wide stencil. Harness (a subprocess on two forced host devices, compared to 1e-12 of the probes'
scale): `tests/two_devices.py`."""

import pytest
from two_devices import assert_two_devices_match

SCENES = {
    "2d": """
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
""",
    "rz": """
from difflattice.lattice import Edges
from difflattice.lattice.grid import make_grid
from difflattice.lattice.medium import Medium
from difflattice.solver import simulate, grid_sharding
from difflattice.solver.sensors import Sensors
from difflattice.solver.sources import ToneBurst, disc_transducer

def cases():
    g = make_grid(frequency_hz=50e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(64, 40), dtype="float64", kind="rz")
    src = disc_transducer(g, radius_m=6.4 * g.dx_m, signal=ToneBurst(50e3, 3))
    sens = Sensors(probes=[(40, 0), (30, 20)], p_max=True, phasor_cells=[(35, 5), (20, 25)])
    for edges in (Edges.axisymmetric("rigid", "pml", "pml", thickness_cells=8), Edges.axisymmetric("rigid", "rigid", "rigid")):
        yield (
            simulate(g, Medium(343.0, 1.2), src, sens, n_steps=140, edges=edges),
            simulate(g, Medium(343.0, 1.2), src, sens, n_steps=140, edges=edges, sharding=grid_sharding()),
        )
""",
    "3d": """
from difflattice.lattice import Edges, Medium
from difflattice.lattice.geometry3d import Sphere, rasterise3d
from difflattice.lattice.grid import make_grid
from difflattice.solver import Sensors, ToneBurst, grid_sharding, simulate
from difflattice.solver.sources import disc_transducer_3d

def cases():
    g = make_grid(frequency_hz=40e3, cells_per_wavelength=8, c_max_m_s=343.0, shape=(40, 30, 28), kind="3d",
                  dtype="float64")
    ball = Sphere(jnp.array([28.0, 15.3, 14.2]) * g.dx_m, jnp.asarray(4.4 * g.dx_m))
    med = Medium(343.0, 1.2, rigid=rasterise3d(ball, g))
    src = disc_transducer_3d(g, (12 * g.dx_m, 15 * g.dx_m, 14 * g.dx_m), (1, 0, 0), diameter_m=6 * g.dx_m,
                          signal=ToneBurst(40e3, 2))
    sens = Sensors(probes=[(20, 15, 14), (30, 8, 20)], p_max=True, phasor_cells=[(22, 12, 10), (18, 20, 16)])
    for edges in (Edges.all("pml", thickness_cells=6), Edges.all("rigid")):
        yield (
            simulate(g, med, src, sens, n_steps=80, edges=edges),
            simulate(g, med, src, sens, n_steps=80, edges=edges, sharding=grid_sharding(ndim=3)),
        )
""",
}


# the 3-D default stencil (19-point isotropic), sharded along x (voxel obstacles: its build-time check
# measures the operator's spectrum with cut cells)
SCENES["3d-isotropic"] = (
    SCENES["3d"]
    .replace('kind="3d",', 'kind="3d", stencil="isotropic", courant=0.86,')
    .replace("rigid=rasterise3d(ball, g)", "rigid=(rasterise3d(ball, g) > 0.5).astype(g.jnp_dtype)")
)
assert 'stencil="isotropic"' in SCENES["3d-isotropic"]

# the 3-D wide stencil (25 points: second axis neighbours, a two-cell halo that XLA's partitioner
# exchanges), cut-cell obstacles and the split-field PML (whose face values reach two cells)
SCENES["3d-wide"] = (
    SCENES["3d"]
    .replace('kind="3d",', 'kind="3d", stencil="wide", courant=0.595,')
    .replace('(Edges.all("pml", thickness_cells=6), Edges.all("rigid"))', '(Edges.all("pml", thickness_cells=6),)')
)
assert 'stencil="wide"' in SCENES["3d-wide"]


@pytest.mark.parametrize("kind", list(SCENES))
def test_two_device_sharding_matches_one_device(kind):
    assert_two_devices_match(SCENES[kind])
