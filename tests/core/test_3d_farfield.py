"""The 3-D Kirchhoff-Helmholtz transform (`observe/farfield3d.py`) against exact fields.

Shell phasors of an exact point-source field exp(ikr)/(4 pi r) (continuum, source off the box
centre) are transformed to a finite range and to the far-field pattern and compared with the
exact values. The transform's own error is the two-shell sampling: the shell mean is off by
(k h)^2 / 8 and the difference by (k h)^2 / 24 along the normal (module docstring), so the
tolerance is (k h)^2 / 6: 1.6 % at 20 and 0.41 % at 40 cells per wavelength, and the error must
fall with resolution (second order: more than 3x from 20 to 40).
"""

import math
from types import SimpleNamespace

import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.observe.farfield3d import BoxSurface, box_around_3d, directions_in_plane, far_field, field_at


def _grid(k):
    # the transform needs omega (rad/step), the courant number and metre -> cell conversion
    return SimpleNamespace(hz_to_lattice_omega=lambda f: 0.5 * k, frequency_hz=1.0, courant=0.5, m_to_cells=lambda r: r)


def _errors(ppw):
    k = 2 * math.pi / ppw
    box = BoxSurface((0, 0, 0), (30, 24, 20))
    src = np.array([12.3, 10.2, 9.7])
    r = np.linalg.norm(box.cells - src, axis=1)
    ph = jnp.asarray(np.exp(1j * k * r) / (4 * math.pi * r))
    dirs = np.concatenate(
        [
            directions_in_plane([1, 0, 0], [0, 1, 0], np.linspace(-180, 180, 25)),
            directions_in_plane([0, 0, 1], [1, 1, 0], np.linspace(-90, 90, 13)),
        ]
    )
    g = _grid(k)
    near = np.asarray(far_field(ph, box, g, dirs, 400.0, centre_cells=src, dispersion="continuum"))
    exact = np.exp(1j * k * 400) / (4 * math.pi * 400)
    F = np.asarray(far_field(ph, box, g, dirs, None, centre_cells=src, dispersion="continuum"))
    return np.abs(near / exact - 1).max(), np.abs(4 * math.pi * F - 1).max(), (k * 1.0) ** 2 / 6


def test_point_source_range_and_pattern():
    e20, f20, tol20 = _errors(20)
    e40, f40, tol40 = _errors(40)
    assert e20 < tol20 and f20 < tol20, (e20, f20)
    assert e40 < tol40 and f40 < tol40, (e40, f40)
    assert e20 / e40 > 3 and f20 / f40 > 3


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


def test_baffled_box_uses_the_image():
    """A source 1.8 cells in front of a rigid baffle (the plane x = -1/2): the exact field is the
    source plus its mirror image; the box without its face on the baffle, continued with the
    image Green's function, gives it (same (k h)^2 / 6 tolerance at 40 cells per wavelength)."""
    k = 2 * math.pi / 40
    box = BoxSurface((0, 0, 0), (20, 24, 22), baffle="x_lo")
    assert box.n_samples == len(box.samples()[0]) == 2 * (21 * 25 + 21 * 23 + 25 * 23) - 25 * 23
    src = np.array([1.3, 11.6, 10.2])
    img = src * [-1, 1, 1] + [-1.0, 0, 0]
    field = lambda x: sum(
        np.exp(1j * k * np.linalg.norm(x - s, axis=-1)) / (4 * math.pi * np.linalg.norm(x - s, axis=-1))
        for s in (src, img)
    )
    ph = jnp.asarray(field(box.cells.astype(float)))
    dirs = directions_in_plane([1, 0, 0], [0, 1, 1], np.linspace(-85, 85, 18))
    g = _grid(k)
    near = np.asarray(far_field(ph, box, g, dirs, 500.0, centre_cells=[-0.5, 11.6, 10.2], dispersion="continuum"))
    exact = field(np.array([-0.5, 11.6, 10.2]) + 500.0 * dirs)
    assert np.abs(near / exact - 1).max() < k**2 / 6
    with pytest.raises(ValueError, match="starts at cell 0"):
        BoxSurface((2, 0, 0), (20, 24, 22), baffle="x_lo")
    assert box_around_3d(np.array([[0, 5, 5], [0, 9, 9]]), 3, baffle="x_lo").lo == (0, 2, 2)
