"""Gradient-based horn design (first piece of the design work): a differentiable horn in front of
a line transducer, a differentiable beam objective, gradients through the whole simulation.

The horn is two rigid walls leaving the ends of the transducer's face at a half-angle for a
length (metres, degrees: arrays, so gradients reach them), rasterised smoothly into a rigid
occupancy. The beam is evaluated by the Kirchhoff-Helmholtz transform on a box that encloses the
transducer and the horn, at any range. Objective: the 2-D directivity index
DI = 10 log10(|p(0)|^2 / mean_theta |p(theta)|^2) over the front half-plane.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..farfield import BoxContour, far_field
from ..geometry import Segment, Union, rasterise
from ..grid import Grid, make_grid
from ..lattice import Edges
from ..medium import Medium
from ..sensors import Sensors
from ..solver import simulate
from ..source import ToneBurst, line_transducer


class HornProblem(eqx.Module):
    """Static set-up: grid, transducer (face diameter, position), contour, run length."""

    grid: Grid
    face_m: float = eqx.field(static=True)
    x0_m: float = eqx.field(static=True)
    y0_m: float = eqx.field(static=True)
    wall_m: float = eqx.field(static=True)
    contour: BoxContour
    n_steps: int = eqx.field(static=True)
    angles_deg: tuple[float, ...] = eqx.field(static=True)

    def horn(self, half_angle_deg, length_m):
        a = jnp.radians(half_angle_deg)
        top0 = jnp.array([self.x0_m, self.y0_m + self.face_m / 2 + self.wall_m])
        bot0 = jnp.array([self.x0_m, self.y0_m - self.face_m / 2 - self.wall_m])
        d = jnp.stack([jnp.cos(a), jnp.sin(a)]) * length_m
        return Union((Segment(top0, top0 + d, jnp.asarray(self.wall_m)),
                      Segment(bot0, bot0 + d * jnp.array([1.0, -1.0]), jnp.asarray(self.wall_m))))

    def pattern(self, half_angle_deg, length_m):
        """Complex far field at 1 m over `angles_deg` for a horn (differentiable in both)."""
        g = self.grid
        occ = rasterise(self.horn(half_angle_deg, length_m), g, "smooth")
        med = Medium(g.c_max_m_s, 1.2, rigid=occ)
        src = line_transducer(g, (self.x0_m, self.y0_m), diameter_m=self.face_m, signal=ToneBurst(g.frequency_hz, 4))
        r = simulate(g, med, src, Sensors(phasor_cells=self.contour.cells), n_steps=self.n_steps,
                     edges=Edges(thickness_cells=12), checkpoint="sqrt")
        centre = (self.x0_m / g.dx_m, self.y0_m / g.dx_m)
        return far_field(r.phasors, self.contour, g, np.asarray(self.angles_deg), 1.0, centre, dispersion="continuum")

    def directivity_db(self, half_angle_deg, length_m):
        p2 = jnp.abs(self.pattern(half_angle_deg, length_m)) ** 2
        on_axis = p2[len(self.angles_deg) // 2]
        return 10 * jnp.log10(on_axis / jnp.mean(p2))


def horn_problem(*, frequency_hz: float = 50e3, cells_per_wavelength: float = 8.0, face_m: float = 0.020,
                 max_length_m: float = 0.040, max_half_angle_deg: float = 20.0, dtype: str = "float64") -> HornProblem:
    """A problem whose grid and contour hold any horn up to the given length and half-angle."""
    c = 343.0
    dx = c / (frequency_hz * cells_per_wavelength)
    pml, gap, wall = 12, 4, 2 * dx
    mouth = face_m / 2 + wall + max_length_m * math.tan(math.radians(max_half_angle_deg)) + wall
    x0 = (pml + gap + 3) * dx
    nx = int(math.ceil((x0 + max_length_m + wall) / dx)) + gap + 3 + pml
    ny = 2 * (int(math.ceil(mouth / dx)) + gap + 3 + pml)
    g = make_grid(frequency_hz=frequency_hz, cells_per_wavelength=cells_per_wavelength, c_max_m_s=c, shape=(nx, ny), dtype=dtype)
    y0 = (ny // 2) * dx
    ix0 = int(round(x0 / dx)) - gap
    contour = BoxContour(ix0, nx - pml - 3, pml + 3, ny - pml - 4)
    reach = math.hypot(nx, ny) / g.courant
    n_steps = int(reach + 8 * g.steps_per_period)
    return HornProblem(g, face_m, x0, y0, wall, contour, n_steps, tuple(float(a) for a in np.linspace(-90.0, 90.0, 91)))


def optimise_horn(problem: HornProblem, *, half_angle_deg: float, length_m: float, max_half_angle_deg: float = 20.0,
                  min_length_m: float = 0.010, max_length_m: float = 0.040, max_steps: int = 30):
    """Maximise the directivity index over the half-angle and length with optimistix BFGS; ranges
    by reparameterisation (sigmoids). Returns (angle_deg, length_m, DI_start_db, DI_end_db, solution)."""
    import jax
    import optimistix as optx

    span = max_length_m - min_length_m

    def unpack(u):
        return max_half_angle_deg * jax.nn.sigmoid(u[0]), min_length_m + span * jax.nn.sigmoid(u[1])

    def loss(u, args):
        return -problem.directivity_db(*unpack(u))

    def logit(p):
        return math.log(p / (1 - p))

    u0 = jnp.array([logit(half_angle_deg / max_half_angle_deg), logit((length_m - min_length_m) / span)])
    start = -float(loss(u0, None))
    sol = optx.minimise(loss, optx.BFGS(rtol=1e-4, atol=1e-4), u0, max_steps=max_steps, throw=False)
    a, L = unpack(sol.value)
    return float(a), float(L), start, -float(loss(sol.value, None)), sol
