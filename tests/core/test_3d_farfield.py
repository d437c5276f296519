"""The 3-D Kirchhoff-Helmholtz surface (`observe/farfield3d.py`): its own refusals and the baffled
box's geometry. The transform against exact point-source fields (free and baffled, (k h)^2 / 6 at
20 and 40 cells per wavelength, second order) is tested with the other kinds' surfaces in
`test_farfield_kinds.py`.
"""

from types import SimpleNamespace

import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.observe.farfield3d import BoxSurface, box_around_3d, field_at


def _grid(k):
    # the transform needs omega (rad/step), the courant number and metre -> cell conversion
    return SimpleNamespace(hz_to_lattice_omega=lambda f: 0.5 * k, frequency_hz=1.0, courant=0.5, m_to_cells=lambda r: r)


def test_near_point_is_refused_and_shapes_checked():
    box = BoxSurface((0, 0, 0), (4, 4, 4))
    g = _grid(0.3)
    ph = jnp.zeros(len(box.cells), jnp.complex128)
    with pytest.raises(ValueError, match="inside the far-field box"):
        field_at(ph, box, g, [[2.5, 2.0, 2.0]])
    with pytest.raises(ValueError, match="surface phasors"):
        field_at(ph[:-1], box, g, [[40.0, 2.0, 2.0]])
    with pytest.raises(ValueError, match="empty far-field box"):
        BoxSurface((0, 0, 0), (4, 0, 4))
    assert box.n_samples * 2 == len(box.cells)
    b2 = box_around_3d(np.array([[10, 10, 10], [12, 10, 11]]), 3)
    assert b2.lo == (7, 7, 7) and b2.hi == (15, 13, 14)
    with pytest.raises(ValueError, match="absorbing layer"):
        b2.check_inside((40, 40, 40), margin=8)


def test_baffled_box_geometry():
    """The baffled box leaves out its face on the baffle (its field, the source plus its image,
    is checked in test_farfield_kinds.test_point_source_field_and_pattern[volume-baffled])."""
    box = BoxSurface((0, 0, 0), (20, 24, 22), baffle="x_lo")
    assert box.n_samples == len(box.samples()[0]) == 2 * (21 * 25 + 21 * 23 + 25 * 23) - 25 * 23
    with pytest.raises(ValueError, match="starts at cell 0"):
        BoxSurface((2, 0, 0), (20, 24, 22), baffle="x_lo")
    assert box_around_3d(np.array([[0, 5, 5], [0, 9, 9]]), 3, baffle="x_lo").lo == (0, 2, 2)
