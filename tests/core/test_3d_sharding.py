"""A 3-D grid split across two devices (along x) gives the single-device numbers, for the
leapfrog (rigid edges) and the split-field PML, with cut-cell obstacles and a disc transducer.
Harness: `tests/two_devices.py`."""

from two_devices import assert_two_devices_match

SCENE = """
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
"""


def test_two_device_sharding_matches_one_device_in_3d():
    assert_two_devices_match(SCENE)


ISOTROPIC = SCENE.replace('kind="3d",', 'kind="3d", stencil="isotropic", courant=0.86,').replace(
    "rigid=rasterise3d(ball, g)", "rigid=(rasterise3d(ball, g) > 0.5).astype(g.jnp_dtype)"
)


def test_two_device_sharding_matches_one_device_with_the_isotropic_stencil():
    """The 3-D default (19-point isotropic) stencil, sharded along x: the same numbers."""
    assert 'stencil="isotropic"' in ISOTROPIC
    assert_two_devices_match(ISOTROPIC)
