"""Echoes of a 3-D pulse-echo run labelled by their image-source delays, and what a sonar would
detect of them.

Every reflecting surface of the scene (each object, and each rigid window side: a wall) gives a
first echo from its point nearest the transducer's centre, at the round-trip path ``2 d``: the
first geometric arrival. Where that point lies inside a face (a plane's foot of the normal, a
post's nearest line) it is the specular reflection, the image source's delay (`first_arrival` =
"specular"); where it lies on an edge or a corner (a door jamb seen from the corridor: neither
face's foot of the normal lies on the face) there is no specular echo, and the first arrival is
the wave diffracted by the edge along the shortest path via it (Keller's edge ray, the onset of
the Biot-Tolstoy response; its spectrum is the incident one times a real, band-smooth factor and
a constant phase, so the envelope keeps the path's delay): `first_arrival` = "edge". Its delay is given twice: in air (``2 d / c``) and on the lattice
(``2 d / v_g``, the lattice's group velocity at the drive frequency along that path,
`observe.analytic3d.group_velocity_3d`: where a tone burst's envelope arrives). The measured
arrival is the envelope peak of the A-scan (Hilbert envelope, parabolic refinement) within half
a burst of the lattice delay, compared in periods of the drive frequency. The level of each echo
(dB re the transmit peak) against a set of detection thresholds is the detection map of the pose.
"""

from __future__ import annotations

import functools
import math
from typing import Any, NamedTuple

import numpy as np

THRESHOLDS_DB = (-20.0, -30.0, -40.0, -50.0, -60.0)
"""Detection thresholds, dB re the transmit peak of the A-scan."""


SIDES = ("x_lo", "x_hi", "y_lo", "y_hi", "z_lo", "z_hi")
"""The window's sides (a rigid one is a wall: "wall x_hi")."""


def surfaces(scene, grid, centre_m=None) -> list[dict[str, Any]]:
    """The reflecting surfaces of a 3-D scene seen from its first transducer's centre (or
    `centre_m`: where its cells lie on the lattice, e.g. their mean): name, the
    nearest point (m), the one-way distance d (m), the unit direction to it, which it is
    (`object`: its index in `scene.objects`, or `side`: the window side, e.g. "x_hi") and its
    first arrival (`first_arrival`: "specular", or "edge" where the point is on an edge or corner,
    `first_arrival_at`) and whether it is `curved` there (a specular point on no plane two
    wavelengths round: a post, a sphere; `under_resolved`). Window sides that
    pass within a transducer radius of the centre (a symmetry plane through the transducer) are
    left out: they give no echo of their own."""
    import jax
    import jax.numpy as jnp

    from ..scene.objects import shape3d

    t = scene.transducers[0]
    c = np.asarray(t.centre_m if centre_m is None else centre_m, float)
    radius = 0.5 * float(t.diameter_m or 0.0)
    out: list[dict[str, Any]] = []
    shapes = []
    for i, o in enumerate(scene.objects):
        shape = shape3d(scene.path, f"objects[{i}]", o)

        def f(p, shape=shape):
            return shape.sdf(p[0], p[1], p[2])

        def nearest(x, f=f):  # the surface point nearest x (the SDF and its gradient)
            p = jnp.asarray(np.asarray(x, float))
            g = np.asarray(jax.grad(f)(p), float)
            return np.asarray(x, float) - float(f(p)) * g / max(np.linalg.norm(g), 1e-30)

        point = nearest(c)
        d = float(np.linalg.norm(point - c))
        u = (point - c) / max(d, 1e-30)
        arrival = _first_arrival(f, point, u, 0.05 * grid.dx_m)
        name = str(o.name or f"{o.shape} {i}")
        shapes.append(shape)
        out.append(
            {
                "surface": name,
                "distance_m": d,
                "point_m": point.tolist(),
                "direction": u.tolist(),
                "object": i,
                "first_arrival": arrival,
                "curved": arrival == "specular" and not _planar(shape, point, -u, grid),
                "nearest": nearest,
            }
        )
    sides = {k for k in SIDES if _side_kind(scene, k) == "rigid"}
    lo = -0.5 * grid.dx_m
    for axis, n in enumerate(grid.shape):
        hi = (n - 0.5) * grid.dx_m
        for side, plane in (("lo", lo), ("hi", hi)):
            key = f"{'xyz'[axis]}_{side}"
            if key not in sides:
                continue
            d = abs(c[axis] - plane)
            if d <= max(radius, grid.dx_m):
                continue
            u = np.zeros(3)
            u[axis] = 1.0 if side == "hi" else -1.0
            point = c.copy()
            point[axis] = plane
            if any(float(sh.sdf(*(jnp.asarray(v) for v in point))) < 0 for sh in shapes):
                continue  # its nearest point lies behind an object: no image-source echo
            out.append(
                {
                    "surface": f"wall {key}",
                    "distance_m": float(d),
                    "point_m": point.tolist(),
                    "direction": u.tolist(),
                    "side": key,
                    "first_arrival": "specular",
                    "curved": False,
                    "nearest": functools.partial(_on_plane, axis=axis, plane=plane),
                }
            )
    return sorted(out, key=lambda s: s["distance_m"])


FIRST_ARRIVAL = {
    "specular": "specular reflection: the image source's delay",
    "edge": "edge diffraction: no specular point on the faces, the shortest path via the nearest edge point",
}
"""What each `first_arrival` of `surfaces` means."""


def _first_arrival(sdf, point, u, eps_m: float) -> str:
    """ "specular" if the surface's outward normal round `point` (the SDF's gradient just inside
    it, `eps_m` along `u`, the direction from the transducer, and as far aside each way) points
    back along the ray, else "edge": the nearest point lies on an edge or a corner, where the
    normal inside jumps from one face's to the other's (on the edge's bisector too)."""
    import jax
    import jax.numpy as jnp

    u = np.asarray(u, float)
    e1 = np.cross(u, [0.0, 0.0, 1.0] if abs(u[2]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    grad = jax.grad(sdf)
    for aside in (0 * e1, e1, -e1, e2, -e2):
        g = np.asarray(grad(jnp.asarray(np.asarray(point, float) + eps_m * (u + aside))), float)
        if -float(g @ u) / max(float(np.linalg.norm(g)), 1e-30) < 0.999:
            return "edge"
    return "specular"


def _side_kind(scene, key: str) -> str:
    """A window side's edge kind: its own, or the `[edges] kind` of every side."""
    return getattr(scene.edges, key) or scene.edges.kind


def _on_plane(x, *, axis: int, plane: float) -> np.ndarray:
    p = np.array(x, float)
    p[axis] = plane
    return p


class Mirror(NamedTuple):
    """A plane the transducer sees itself in: a rigid window side (`side`) or an object's planar
    face. `image`: the transducer's centre mirrored in it; `centre`: the centre; `point`, `normal`:
    a point of the plane and its unit normal towards the transducer; `reflects(a, b, away)`: whether
    the path a -> b (b on the image's side) reflects off the plane on the solid, in free air (not in
    a door gap of a wall's plane, not behind an object, inside the window), tested half a cell off
    the plane and, along `away`, off the echoing surface (a corner path meets the mirror where the
    surface stands on it)."""

    image: np.ndarray
    centre: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    side: bool
    reflects: Any
    clear: Any  # clear(*points): whether the polyline through them runs in air (no object across it)
    shadow: Any  # shadow(*points): (depth m inside an object at its deepest, where along the polyline m)

    def crossing(self, a, b) -> np.ndarray:
        """Where the segment a -> b meets the plane (a path's reflection point; a if parallel)."""
        r = _plane_crossing(self.point, self.normal, a, b)
        return np.asarray(a, float) if r is None else r

    def reflected(self, x) -> np.ndarray:
        """A point mirrored in the plane."""
        x = np.asarray(x, float)
        return x - 2 * float((x - self.point) @ self.normal) * self.normal

    def mirrored(self, v) -> np.ndarray:
        """A direction mirrored in the plane (the image transducer's axis)."""
        v = np.asarray(v, float)
        return v - 2 * float(v @ self.normal) * self.normal


def _plane_crossing(point, normal, a, b) -> np.ndarray | None:
    """Where the line a -> b meets the plane through `point` with `normal` (None if parallel)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    den = float(normal @ (b - a))
    return None if abs(den) < 1e-15 else a + float(normal @ (point - a)) / den * (b - a)


def _window(grid) -> tuple[np.ndarray, np.ndarray]:
    """The window's low and high corners (m): the rigid sides' planes, half a cell outside the
    first and last cell centres."""
    return np.full(3, -0.5 * grid.dx_m), (np.asarray(grid.shape, float) - 0.5) * grid.dx_m


def _shapes(scene) -> list:
    """The scene's objects as 3-D shapes (their signed distances, m)."""
    from ..scene.objects import shape3d

    return [shape3d(scene.path, f"objects[{i}]", o) for i, o in enumerate(scene.objects)]


def find_mirrors(scene, grid, centre_m=None, found=None) -> list[Mirror]:
    """The transducer's mirrors: each rigid window side and each object's planar face whose point
    nearest the transducer is specular (`found`: `surfaces` of the scene, else computed), planes
    met twice counted once. A path via a mirror counts only where it `reflects` on the solid."""
    import jax.numpy as jnp

    t = scene.transducers[0]
    c = np.asarray(t.centre_m if centre_m is None else centre_m, float)
    eps = 0.5 * grid.dx_m
    lo_w, hi_w = _window(grid)
    shapes = _shapes(scene)

    def sdf(x) -> float:  # the objects' union (metres; > 0 in air)
        p = [jnp.asarray(float(v)) for v in x]
        return min((float(sh.sdf(*p)) for sh in shapes), default=math.inf)

    def shadow(*pts) -> tuple[float, float]:
        """(how deep, m, the polyline through `pts` runs inside an object at its deepest, ends
        excepted; 0 in air all along, and how far along it, m, that point lies)."""
        deepest, at, run = 0.0, 0.0, 0.0
        for a, b in zip(pts[:-1], pts[1:]):
            a, b = np.asarray(a, float), np.asarray(b, float)
            seg = float(np.linalg.norm(b - a))
            n = max(2, int(seg / (0.5 * grid.dx_m)))
            f = np.linspace(0.0, 1.0, n + 1)[1:-1]
            f = f[(f * seg > 2 * grid.dx_m) & ((1 - f) * seg > 2 * grid.dx_m)]
            if len(f) and shapes:
                q = a[None, :] + f[:, None] * (b - a)[None, :]
                x, y, z = (jnp.asarray(q[:, i]) for i in range(3))
                v = np.min([np.asarray(sh.sdf(x, y, z), float) for sh in shapes], axis=0)
                k = int(np.argmin(v))
                if -v[k] > deepest:
                    deepest, at = float(-v[k]), run + float(f[k]) * seg
            run += seg
        return deepest, at

    def clear(*pts) -> bool:  # the polyline through `pts` in air: no object across it (ends excepted)
        return shadow(*pts)[0] <= 0.25 * grid.dx_m

    def reflects_fn(point, normal, side: bool):
        def reflects(a, b, away=None) -> bool:
            r = _plane_crossing(point, normal, a, b)
            if r is None:
                return False
            if np.any(r < lo_w - eps) or np.any(r > hi_w + eps):
                return False  # outside the window
            off = np.zeros(3) if away is None else eps * np.asarray(away, float)  # off the echoing surface at a corner
            if sdf(r + eps * normal + off) <= 0:
                return False  # an object stands in front of the plane there
            return side or sdf(r - eps * normal + off) < 0  # an object's face: solid behind it (not a gap)

        return reflects

    out: list[Mirror] = []

    def add(point, normal, side: bool) -> None:
        point, normal = np.asarray(point, float), np.asarray(normal, float)
        for m in out:
            if abs(float(m.normal @ normal)) > 1 - 1e-9 and abs(float(m.normal @ (point - m.point))) < 0.1 * grid.dx_m:
                return
        image = c - 2 * float((c - point) @ normal) * normal
        out.append(Mirror(image, c, point, normal, side, reflects_fn(point, normal, side), clear, shadow))

    for axis, n in enumerate(grid.shape):
        for side, plane in (("lo", -0.5 * grid.dx_m), ("hi", (n - 0.5) * grid.dx_m)):
            if _side_kind(scene, f"{'xyz'[axis]}_{side}") == "rigid":
                point = c.copy()
                point[axis] = plane
                normal = np.zeros(3)
                normal[axis] = 1.0 if side == "lo" else -1.0
                add(point, normal, True)
    for s in found if found is not None else surfaces(scene, grid, centre_m):
        if "object" in s and s["first_arrival"] == "specular" and not s["curved"]:
            add(np.asarray(s["point_m"], float), -np.asarray(s["direction"], float), False)
    return out


def _planar(shape, point, normal, grid) -> bool:
    """Whether `shape`'s face through `point` (outward `normal`) is a plane over two wavelengths
    round it: on the surface there, with the same normal just inside."""
    import jax
    import jax.numpy as jnp

    p, n = np.asarray(point, float), np.asarray(normal, float)
    reach = 2.0 * grid.dx_m * grid.cells_per_wavelength
    grad = jax.grad(lambda q: shape.sdf(q[0], q[1], q[2]))
    e1 = np.cross(n, [0.0, 0.0, 1.0] if abs(n[2]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    for q in (p + reach * e1, p - reach * e1, p + reach * e2, p - reach * e2):
        g = np.asarray(grad(jnp.asarray(q - 0.5 * grid.dx_m * n)), float)  # just inside the face
        on = abs(float(shape.sdf(*(jnp.asarray(v) for v in q)))) < 0.05 * grid.dx_m
        if not (on and float(g @ n) / max(float(np.linalg.norm(g)), 1e-30) > 0.9999):
            return False
    return True


CURVED_MIN_CELLS_PER_WAVELENGTH = 9.0
"""Below this a curved surface's first echo is not its image source's: the cells whose centre
lies inside make a staircase whose steps scatter late energy and, at 6 cells per wavelength,
halve the specular echo. Measured (docs/three_d.md, "A round post"): a 50 mm post 0.6 m from the
corridor's disc between a rigid floor and ceiling, its echo isolated, first arrival -0.23 +- 0.37
periods and 6 dB low at 6 cells per wavelength (+0.81 +- 0.25 with smooth rasterisation, +0.13 +-
0.27 on the standard stencil), 0.000 +- 0.069 at 9 (smooth: +0.122 +- 0.023, the smooth
surface's place not modelled), where a plane at the same place gives -0.002 +- 0.022 at 6
(`benchmarks/round_post.py`)."""


UNDER_RESOLVED = (
    f"a curved surface on fewer than {CURVED_MIN_CELLS_PER_WAVELENGTH:g} cells per wavelength: its rasterised "
    "surface scatters and its first echo is not its image source's (docs/three_d.md, 'A round post')"
)
"""What an echo row's `under_resolved` means (the console lines give it)."""


def under_resolved(s: dict, grid) -> bool:
    """Whether surface `s` (a row of `surfaces`) is curved where it echoes and the grid is coarser
    than `CURVED_MIN_CELLS_PER_WAVELENGTH`: its fitted arrival then says so."""
    return bool(s.get("curved")) and grid.cells_per_wavelength < CURVED_MIN_CELLS_PER_WAVELENGTH


def mirror_paths(s: dict, m: Mirror) -> list[tuple[float, float, str, np.ndarray]]:
    """The round trips of surface `s` via mirror `m` (method of images, monostatic), as (length,
    multiplicity, "cross" or "double", the point on `s`):

    - a surface the mirror maps onto itself (a wall or a post square to a floor: the point of `s`
      nearest T' is the mirror image of the one nearest T) has one more image, T reflected in `s`
      and the mirror: the corner path T -> S -> T' ("cross", once: it is its own reverse);
    - any other (a post in front of a side wall) has the two paths T -> S -> T' and T' -> S -> T
      ("cross", each the other's reverse, both rays) and T' -> S -> T' ("double": out and back via
      the mirror).

    A path counts only where it meets the mirror on its solid (`Mirror.reflects`) and runs in air
    (`Mirror.clear`: the near jamb shadows a door recess's inner corner)."""
    nearest = s["nearest"]
    p = np.asarray(s["point_m"], float)
    c, image = m.centre, m.image
    pm = nearest(0.5 * (image + c))
    cross = float(np.linalg.norm(pm - c) + np.linalg.norm(pm - image))
    pd = nearest(image)
    away = -np.asarray(s["direction"], float)  # from the surface back towards the transducer
    out: list[tuple[float, float, str, np.ndarray]] = []
    if not (m.reflects(pm, image, away) and m.clear(c, pm, m.crossing(pm, image), c)):
        return out
    if np.linalg.norm(pd - m.reflected(p)) <= 1e-6 * max(float(np.linalg.norm(p - c)), 1e-30):
        return [(cross, 1.0, "cross", pm)]
    out.append((cross, 2.0, "cross", pm))
    if m.reflects(pd, image, away) and m.clear(c, m.crossing(pd, image), pd):
        out.append((2 * float(np.linalg.norm(pd - image)), 1.0, "double", pd))
    return out


class Guide(NamedTuple):
    """Two rigid window sides facing each other across `axis` (a floor and a ceiling) with every
    object an extrusion between them: the scene is invariant along `axis` inside the window, so the
    method of images is exact there: each path of a surface that is itself invariant (a wall or a
    post standing floor to ceiling) has a copy via every image of the transducer in the pair, the
    unfolded path tilted by the image's offset (`offsets_m`, signed, each image once)."""

    axis: int
    offsets_m: tuple[float, ...]

    def carries(self, s: dict) -> bool:
        """Whether surface `s` is invariant along the guide's axis (its echo has the images)."""
        return (
            abs(float(np.asarray(s["direction"], float)[self.axis])) < 1e-9
            and s.get("side", "")[:1] != "xyz"[self.axis]
        )

    def is_plane(self, m: Mirror) -> bool:
        """Whether mirror `m` is one of the guide's two planes (its images are the guide's own)."""
        return abs(abs(float(m.normal[self.axis])) - 1.0) < 1e-9


def _reach(grid, within_m: float) -> float:
    """How far off (m) an image of the transducer may lie and add less than `within_m` to a round
    trip inside the window (twice its diagonal)."""
    diagonal = float(np.linalg.norm(np.asarray(grid.shape, float) * grid.dx_m))
    return math.sqrt(4 * diagonal * within_m + within_m**2)


def find_guides(scene, grid, centre_m, reach_m: float) -> list[Guide]:
    """The scene's `Guide`s (each axis whose two window sides are rigid, across which the
    transducer's axis lies and along which every object is an extrusion through the window: its
    signed distance the same at every height, sampled at random points in air), with the
    transducer's images within `reach_m` of it: a floor and a ceiling; in an empty duct, its
    side walls as well."""
    import jax.numpy as jnp

    t = scene.transducers[0]
    c = np.asarray(centre_m, float)
    shapes = _shapes(scene)
    lo_w, hi_w = _window(grid)
    rng = np.random.default_rng(0)
    guides = []
    for axis in range(3):
        key = "xyz"[axis]
        if _side_kind(scene, f"{key}_lo") != "rigid" or _side_kind(scene, f"{key}_hi") != "rigid":
            continue
        if abs(float(_transducer_axis(t)[axis])) > 1e-9:
            continue
        pts = lo_w + rng.random((256, 3)) * (hi_w - lo_w)
        levels = np.linspace(lo_w[axis], hi_w[axis], 7)
        invariant = True
        for sh in shapes:
            vals = []
            for z in levels:
                q = pts.copy()
                q[:, axis] = z
                vals.append(np.asarray(sh.sdf(*(jnp.asarray(q[:, i]) for i in range(3))), float))
            v = np.stack(vals)
            air = np.all(v > 0, axis=0)
            if not np.any(air) or np.max(np.ptp(v[:, air], axis=0)) > 1e-6 * grid.dx_m:
                invariant = False
                break
        if not invariant:
            continue
        height = hi_w[axis] - lo_w[axis]
        u0 = c[axis] - lo_w[axis]
        offsets: set[float] = set()
        k_max = int(reach_m / (2 * height)) + 2
        for k in range(-k_max, k_max + 1):
            for off in (2 * k * height, 2 * k * height - 2 * u0):
                if 1e-9 < abs(off) <= reach_m and not any(abs(off - o) < 1e-6 * grid.dx_m for o in offsets):
                    offsets.add(off)
        guides.append(Guide(axis, tuple(sorted(offsets, key=abs))))
    return guides


def _transducer_axis(transducer) -> np.ndarray:
    """The unit direction a transducer faces (a disc's `axis`, default +x)."""
    a = np.asarray(getattr(transducer, "axis", None) or (1.0, 0.0, 0.0), float)
    return a / np.linalg.norm(a)


def shadowed_paths(s: dict, mirrors, wavelength_m: float, within_m: float) -> list[float]:
    """The round trips of `s` via a mirror (`mirror_paths`'s corner paths) that reflect on the
    mirror's solid but whose straight line runs through an object less deep than the first Fresnel
    zone's radius sqrt(lambda d1 d2 / (d1 + d2)) there (d1, d2 along the unfolded path): shadowed
    geometrically, so not in the model echo, but grazing an edge (a door recess's inner corner
    seen past the near jamb), where diffraction brings much of them back. Their lengths (m), those
    adding less than `within_m` to the direct round trip, as predicted arrivals of their own for a
    fit (`fit_first_arrival`'s `others_steps`)."""
    out: list[float] = []
    away = -np.asarray(s["direction"], float)
    for m in mirrors:
        c, image = m.centre, m.image
        pm = s["nearest"](0.5 * (image + c))
        if not m.reflects(pm, image, away):
            continue
        pts = (c, pm, m.crossing(pm, image), c)
        depth, at = m.shadow(*pts)
        length = float(sum(np.linalg.norm(np.asarray(b) - np.asarray(a)) for a, b in zip(pts[:-1], pts[1:])))
        if depth <= 0.0 or m.clear(*pts):
            continue
        if depth < math.sqrt(wavelength_m * at * (length - at) / length) and length - 2 * s["distance_m"] < within_m:
            out.append(length)
    return out


def _sin_off(axis, direction) -> float:
    """The sine of the angle between `axis` and `direction`."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    return math.sqrt(max(0.0, 1.0 - float(a @ d) ** 2))


def _jinc(x):
    """2 J1(x) / x (1 at 0), elementwise."""
    from scipy.special import j1

    x = np.asarray(x, float)
    small = np.abs(x) < 1e-9
    return np.where(small, 1.0, 2 * j1(np.where(small, 1.0, x)) / np.where(small, 1.0, x))


def shadowed_lags_steps(s: dict, mirrors, grid, within_m: float) -> list[float]:
    """`shadowed_paths` of `s` as lags after its direct round trip, steps (the lattice's group
    velocity along its direction): the fit's predicted arrivals."""
    wavelength = grid.dx_m * grid.cells_per_wavelength
    step_m = grid.dx_m * _vg(grid, s["direction"])
    return [(p - 2 * s["distance_m"]) / step_m for p in shadowed_paths(s, mirrors, wavelength, within_m)]


class PathWeight(NamedTuple):
    """A round trip's weight: its multiplicity and the disc's far-field directivity 2 J1(x) / x,
    x = ka sin(theta), out of its source and into its receiver. `float()` gives it at the drive
    frequency; called with frequency / drive frequency (an array) it gives it across the band
    (ka scales with frequency: a path near a null of the lobe changes across the burst's band)."""

    times: float
    ka: float
    sin_out: float
    sin_in: float

    def __float__(self) -> float:
        return float(self(1.0))

    def __call__(self, ratio):
        return self.times * _jinc(self.ka * ratio * self.sin_out) * _jinc(self.ka * ratio * self.sin_in)


def weighted_paths(s: dict, mirrors, within_m: float, transducer, wavelength_m: float, guides=()):
    """The round trips that make one echo with the direct one (2 d): direct, and via the
    transducer's image T' in each mirror (`find_mirrors`: a floor under it, a corridor's side
    walls; `mirror_paths`) adding less than `within_m`, each weighted by its multiplicity and the disc's
    directivity at the drive frequency out of its source and into its receiver (the image's axis
    mirrored): a path that leaves the beam counts for what the disc sends and hears along it. In
    `guides` (`find_guides`: a rigid floor and ceiling, the scene an extrusion between
    them) a surface they carry has each of these paths again via every image of the transducer in
    their planes, the unfolded path tilted by the image's offset (its legs' directivity at the tilt).
    The weights are `PathWeight`s (a float at the drive frequency, a function across the band)."""
    import itertools

    d = s["distance_m"]
    axis = _transducer_axis(transducer)
    ka = math.pi * float(getattr(transducer, "diameter_m", None) or 0.0) / wavelength_m  # 0: no directivity
    carry = [g for g in guides if g.carries(s)]
    direction = np.asarray(s["direction"], float)
    legs = [(2 * d, 1.0, direction, axis, direction, axis)]  # (length, times, out leg, its axis, in leg, its axis)
    for m in mirrors:
        if any(g.is_plane(m) for g in carry):
            continue  # the guides' images below
        axis_i = m.mirrored(axis)  # the image transducer's
        for length, times, kind, q in mirror_paths(s, m):
            if 1e-6 < length - 2 * d < within_m:
                out = (q - m.centre, axis) if kind == "cross" else (q - m.image, axis_i)
                legs.append((length, times, *out, q - m.image, axis_i))
    offsets = []
    for combo in itertools.product(*[(0.0,) + g.offsets_m for g in carry]):
        v = np.zeros(3)
        for g, o in zip(carry, combo):
            v[g.axis] = o
        offsets.append(v)
    paths, weights = [], []
    for length, times, v_out, a_out, v_in, a_in in legs:
        for off in offsets:
            tilted = math.hypot(length, float(np.linalg.norm(off)))
            if tilted > length and not tilted - 2 * d < within_m:
                continue
            u_out = np.asarray(v_out, float) / np.linalg.norm(v_out) * length + off
            u_in = np.asarray(v_in, float) / np.linalg.norm(v_in) * length + off
            paths.append(tilted)
            weights.append(PathWeight(float(times), ka, _sin_off(a_out, u_out), _sin_off(a_in, u_in)))
    return paths, weights


def envelope(x: np.ndarray) -> np.ndarray:
    """The Hilbert envelope |x + i H x| (FFT)."""
    n = len(x)
    spec = np.fft.fft(x)
    h = np.zeros(n)
    h[0] = 1.0
    if n % 2 == 0:
        h[n // 2] = 1.0
        h[1 : n // 2] = 2.0
    else:
        h[1 : (n + 1) // 2] = 2.0
    return np.abs(np.fft.ifft(spec * h))


def path_phase(grid, w: np.ndarray, keep: np.ndarray, paths_m, weights, direction, *, lattice: bool) -> np.ndarray:
    """The transfer of paths `paths_m` (m, summed with `weights`: numbers, or `PathWeight`s taken
    at each frequency) along `direction` at lattice frequencies `w` (rad/step): each frequency delayed by its phase delay, the lattice's
    (`analytic3d.lattice_wavenumber_3d`, the grid's stencil) or the air's. Frequencies above the
    lattice's band edge are dropped from `keep` (in place)."""
    from ..observe.analytic3d import lattice_wavenumber_3d

    slowness = np.zeros_like(w)  # phase delay per cell, steps
    for j in np.flatnonzero(keep):
        if lattice:
            try:
                k = float(lattice_wavenumber_3d(w[j], grid.courant, direction, stencil=grid.stencil))
            except ValueError:  # above the band edge
                keep[j] = False
                continue
        else:
            k = w[j] / grid.courant
        slowness[j] = k / w[j]
    ratio = w / grid.omega  # frequency / the drive's: a `PathWeight` across the band
    return sum(
        (wt(ratio) if callable(wt) else wt) * np.exp(-1j * w * slowness * p / grid.dx_m)
        for p, wt in zip(paths_m, weights)
    )


def model_echo(grid, ref: np.ndarray, n: int, paths_m, weights, direction) -> np.ndarray:
    """The model echo on an A-scan's `n` samples: `ref` (the drive's samples) carried along
    `paths_m` (summed with `weights`) with the lattice's dispersion relation along `direction`,
    advanced one step (the soft source's lead: the A-scan's sample i is at (i + 1) dt)."""
    n_fft = 1 << int(math.ceil(math.log2(2 * max(n, len(ref)))))
    r = np.fft.rfft(ref, n_fft)
    w = 2 * np.pi * np.fft.rfftfreq(n_fft)  # rad/step
    keep = np.abs(r) > 1e-6 * np.abs(r).max()
    keep[0] = False
    phase = path_phase(grid, w, keep, paths_m, weights, direction, lattice=True)
    return np.fft.irfft(np.where(keep, r * phase * np.exp(1j * w), 0.0), n_fft)[:n]


def fit_first_arrival(
    trace, template, lag_steps: float, burst_steps: float, steps_per_period: float, others_steps=(), gate_step: int = 0
):
    """`observe.arrivals.fit_arrivals` of copies of `template` (a model echo whose burst starts
    at time of flight `lag_steps`) to `trace` from half a burst before it to two bursts after (not
    before `gate_step`), from the template where it is and the `others_steps` (other predicted
    arrivals, steps relative to it, those inside the window); the first arrival's delay is its
    excess over the template's, in steps. Where the window holds too few independent samples of
    the template's band for every prediction, the farthest prediction goes first; for the
    template's own (a narrow band: a path at the edge of the disc's lobe, a wall beside it) the
    window then grows by half a burst at a time, up to `MAX_WINDOW_BURSTS` after the start."""
    from ..observe.arrivals import Pulse, fit_arrivals

    start = lag_steps - 1  # the template's burst starts on this sample (its one-step lead)
    lo = max(int(math.floor(start - 0.5 * burst_steps)), gate_step)
    after = 2.0
    hi = int(math.ceil(start + after * burst_steps))
    others = sorted(
        (float(d) for d in others_steps if lo < start + d < hi - 0.5 * burst_steps and abs(d) > 0.5), key=abs
    )
    pulse = Pulse(template, len(trace))
    while True:
        try:
            return fit_arrivals(trace, pulse, [0.0] + others, lo, hi, samples_per_period=steps_per_period)
        except ValueError as e:  # the window holds too few independent samples for every prediction:
            if "too few for" not in str(e):
                raise
            if others:  # the farthest from the surface's goes first
                others.pop()
                continue
            wider = int(math.ceil(start + (after + 0.5) * burst_steps))
            if after + 0.5 > MAX_WINDOW_BURSTS or wider > len(trace):
                raise
            after, hi = after + 0.5, wider


MAX_WINDOW_BURSTS = 3.0
"""How far after its start (bursts) `fit_first_arrival` may read an echo: the run without a
surface (`echoes_isolated`) records three bursts after its echo starts."""


def propagated_envelope_peak_s(
    grid, path_m, direction, cycles: float, n: int, *, lattice: bool = True, weights=None
) -> float:
    """When the envelope of the drive burst (hann, `cycles` cycles) peaks after travelling
    `path_m` along `direction`: every frequency of the burst delayed by its own phase delay, the
    lattice's (its dispersion relation along that direction, `analytic3d.lattice_wavenumber_3d`)
    or the air's (``path / c``); so the group delay and its spread over the band are both in it.
    `path_m` may be several paths (summed with `weights`: one echo over paths that merge, e.g.
    via a floor's image). On `n` steps; a soft source's one-step lead included."""
    paths = np.atleast_1d(np.asarray(path_m, float))
    wts = [1.0] * len(paths) if weights is None else list(weights)
    from ..solver.sources import ToneBurst

    dt = grid.dt_s
    n_fft = 1 << int(math.ceil(math.log2(2 * n)))
    t = np.arange(n_fft) * dt
    s = np.asarray(ToneBurst(grid.frequency_hz, cycles)(t))
    spec = np.fft.rfft(s)
    w = 2 * np.pi * np.fft.rfftfreq(n_fft)  # rad/step
    keep = np.abs(spec) > 1e-6 * np.abs(spec).max()
    keep[0] = False
    phase = path_phase(grid, w, keep, paths, wts, direction, lattice=lattice)
    spec = np.where(keep, spec * phase, 0.0)
    env = envelope(np.fft.irfft(spec, n_fft))
    k_pk, _, _ = _peak(env, 1, n_fft - 1)
    return k_pk * dt - dt


def _transmit_peak(a: np.ndarray, gate_start_step: int, burst_steps: float) -> float:
    """The transmit's peak: the A-scan before the gate, or over the burst when the gate is at 0."""
    n = max(1, gate_start_step, int(math.ceil(burst_steps)))
    return float(np.abs(a[:n]).max()) or 1.0


def _peak(env: np.ndarray, lo: int, hi: int) -> tuple[float, float, bool]:
    """(fractional index, value, inside) of the envelope's largest value in [lo, hi), refined by
    a parabola through its neighbours; `inside` is False where it lies on the window's edge."""
    lo, hi = max(lo, 1), min(hi, len(env) - 1)
    if hi <= lo:
        return float("nan"), 0.0, False
    k = lo + int(np.argmax(env[lo:hi]))
    a, b, c = env[k - 1], env[k], env[k + 1]
    den = a - 2 * b + c
    dk = 0.5 * (a - c) / den if den < 0 else 0.0
    return k + dk, float(b - 0.25 * (a - c) * dk), lo < k < hi - 1


def label_echoes(t_s, a_scan, scene, grid, *, cycles: float, gate_start_step: int, centre_m=None) -> dict[str, Any]:
    """The echo table of an A-scan (see the module docstring): per surface the delays in air and on
    the lattice, the measured arrival and its error in periods, the level and the detection at
    `THRESHOLDS_DB`."""
    from ..air import SPEED_OF_SOUND_20C_M_S
    from ..observe.analytic3d import group_velocity_3d

    a = np.asarray(a_scan, float)
    t = np.asarray(t_s, float)
    dt = grid.dt_s
    f0 = grid.frequency_hz
    c_air = grid.c_max_m_s if grid.c_max_m_s > 0 else SPEED_OF_SOUND_20C_M_S
    env = envelope(np.where(np.arange(len(a)) >= gate_start_step, a, 0.0))
    transmit = _transmit_peak(a, gate_start_step, cycles / f0 / dt)
    half = 0.5 * cycles / f0
    rows = []
    found = surfaces(scene, grid, centre_m)
    mirrors = find_mirrors(scene, grid, centre_m, found)
    transducer = scene.transducers[0]
    wavelength = grid.dx_m * grid.cells_per_wavelength
    guides = find_guides(scene, grid, transducer.centre_m if centre_m is None else centre_m, _reach(grid, half * c_air))

    def merged(s):  # the round trips that make its echo, weighted by the disc's directivity
        return weighted_paths(s, mirrors, half * c_air, transducer, wavelength, guides)

    def partly(s):  # its corner paths that graze an edge (`shadowed_paths`), within the fit's window
        return shadowed_lags_steps(s, mirrors, grid, 2 * cycles * wavelength)

    fits = _fit_all(a, found, merged, partly, grid, cycles, gate_start_step)
    for s in found:
        path = 2 * s["distance_m"]
        vg = float(group_velocity_3d(grid.omega, grid.courant, s["direction"], stencil=grid.stencil))
        v_lat = vg * grid.dx_m / dt  # m/s
        paths, weights = merged(s)
        t_air = propagated_envelope_peak_s(grid, paths, s["direction"], cycles, len(a), lattice=False, weights=weights)
        t_lat = propagated_envelope_peak_s(grid, paths, s["direction"], cycles, len(a), weights=weights)
        if t_lat - half < gate_start_step * dt:
            continue  # inside the transmit: no echo of its own (e.g. a floor beside the transducer)
        lo = int(round((t_lat - half) / dt))
        hi = int(round((t_lat + half) / dt))
        head = {k: v for k, v in s.items() if k != "nearest"} | {
            "path_m": path,
            "merged_paths_m": [float(p) for p in paths],
            "delay_air_s": t_air,
            "delay_lattice_s": t_lat,
            "group_velocity_m_s": v_lat,
            "under_resolved": under_resolved(s, grid),
        }
        if hi > len(a):  # its echo ends after the record: a row that says so, no arrival or level
            rows.append(head | {"recorded": False, "record_end_s": float(t[-1])})
            continue
        k, level, inside = _peak(env, lo, hi)
        t_meas = t[0] + k * dt if np.isfinite(k) else float("nan")
        level_db = 20 * math.log10(max(level, 1e-300) / transmit)
        rows.append(
            head
            | {
                "arrival_s": t_meas,
                "error_periods": (t_meas - t_lat) * f0,
                "error_periods_air": (t_meas - t_air) * f0,
                "recorded": True,
                "resolved": bool(inside and gate_start_step <= lo),
                "level_db": level_db,
                "detected": {f"{th:g}": bool(level_db >= th) for th in THRESHOLDS_DB},
                "fit": fits.get(s["surface"]),
            }
        )
    return {
        "what": "first echo of each surface: the delay of its first geometric arrival (first_arrival: the image "
        "source's, or the edge path's where no face has a specular point) in air and with the lattice's "
        "group velocity, the A-scan's envelope peak within half a burst of it (error_periods), level dB re the "
        "transmit peak; fit: the first arrival of copies of the surface's model echo fitted to the A-scan from "
        "every surface's predicted delay in the window (observe.arrivals), its excess over the lattice delay "
        "with its standard error and whether it is separable from the arrivals round it",
        "first_arrival": FIRST_ARRIVAL,
        "frequency_hz": f0,
        "burst_cycles": cycles,
        "thresholds_db": list(THRESHOLDS_DB),
        "echoes": rows,
    }


def _fit_all(a, found, merged, partly, grid, cycles: float, gate_start_step: int) -> dict[str, dict]:
    """Per surface the fitted first arrival (`fit_first_arrival`) of the A-scan `a` after the gate:
    the copies started at its model echo (over its round trips `merged(s)`: paths, weights), at
    every other surface's lattice delay in the window and at its partly shadowed paths
    (`partly(s)`: their lags after its own, steps)."""
    from ..solver.sources import ToneBurst

    dt, f0 = grid.dt_s, grid.frequency_hz
    burst = cycles / f0 / dt
    t = np.arange(1, len(a) + 1) * dt
    ref = np.asarray(ToneBurst(f0, cycles)(t), float)[: int(math.ceil(burst)) + 2]
    trace = np.where(np.arange(len(a)) >= gate_start_step, a, 0.0)
    models, shadowed = {}, {}
    for s in found:
        paths, weights = merged(s)
        shadowed[s["surface"]] = partly(s)
        lag = 2 * s["distance_m"] / (grid.dx_m * float(_vg(grid, s["direction"])))  # the group delay, steps
        models[s["surface"]] = (lag, model_echo(grid, ref, len(a), paths, weights, s["direction"]))
    out = {}
    for name, (lag, template) in models.items():
        if lag - 1 < gate_start_step:
            continue
        if lag - 1 + 2.0 * burst > len(a):
            continue  # its window (two bursts after its start) runs past the record's end: not fitted
        others = [o - lag for n, (o, _) in models.items() if n != name] + shadowed[name]
        fit = fit_first_arrival(trace, template, lag, burst, 1 / (f0 * dt), others, gate_start_step)
        first = fit.first_arrival
        out[name] = {
            "error_periods": first.delay * dt * f0,
            "sigma_periods": first.sigma_delay * dt * f0,
            "separable": fit.separable,
            "why": fit.why,
            "n_arrivals": len(fit.arrivals),
            "residual_rel": fit.residual_rel,
        }
    return out


def _vg(grid, direction) -> float:
    from ..observe.analytic3d import group_velocity_3d

    return float(group_velocity_3d(grid.omega, grid.courant, direction, stencil=grid.stencil))


def _label(e: dict) -> str:
    """A surface's name, with "(edge)" where its first arrival is edge-diffracted."""
    return e["surface"] + (" (edge)" if e.get("first_arrival") == "edge" else "")


def _fit_text(e: dict) -> str:
    """The fitted first arrival as a label: ": +0.03 +- 0.01 T" (periods), "not separable" and an
    `under_resolved` curved surface flagged."""
    f = e.get("fit")
    if not f:
        return ""
    return (
        f": {f['error_periods']:+.2f} ± {f['sigma_periods']:.2f} T"
        + ("" if f["separable"] else " (not separable)")
        + (" (curved: under-resolved)" if e.get("under_resolved") else "")
    )


def fit_line(e: dict) -> str:
    """One console line of a surface's fitted first arrival against its lattice delay."""
    f = e.get("fit")
    if e.get("recorded") is False:
        return (
            f"echo {e['surface']!r} ({e.get('first_arrival', 'specular')}): path {e['path_m']:.4f} m, lattice delay "
            f"{e['delay_lattice_s'] * 1e3:.3f} ms: after the record's end ({e['record_end_s'] * 1e3:.3f} ms), not measured"
        )
    head = f"echo {e['surface']!r} ({e.get('first_arrival', 'specular')}): path {e['path_m']:.4f} m, {e['level_db']:.1f} dB"
    note = f"; {UNDER_RESOLVED}" if e.get("under_resolved") else ""
    if not f:
        return f"{head}, envelope peak {e['error_periods']:+.3f} periods vs lattice delay{note}"
    sep = "separable" if f["separable"] else f"not separable: {f['why']}"
    return (
        f"{head}, first arrival {f['error_periods']:+.3f} ± {f['sigma_periods']:.3f} periods vs lattice delay "
        f"(fit of {f['n_arrivals']} arrival(s); {sep}), envelope peak {e['error_periods']:+.3f}{note}"
    )


def plot_labelled(t_s, a_scan, table: dict, gate_start_step: int, path):
    """The A-scan's envelope (dB re the transmit peak) with each surface's lattice delay marked."""
    from matplotlib.figure import Figure

    from .. import plots

    a = np.asarray(a_scan, float)
    ts = np.asarray(t_s, float)
    env = envelope(np.where(np.arange(len(a)) >= gate_start_step, a, 0.0))
    transmit = _transmit_peak(a, gate_start_step, table["burst_cycles"] / table["frequency_hz"] / (ts[1] - ts[0]))
    db = 20 * np.log10(np.maximum(env / transmit, 1e-6))
    fig = Figure(figsize=(9, 4))
    ax = fig.add_subplot()
    t_ms = np.asarray(t_s) * 1e3
    ax.plot(t_ms, db, lw=0.8)
    for i, e in enumerate(e for e in table["echoes"] if e.get("recorded", True)):
        ax.axvline(e["delay_lattice_s"] * 1e3, color="C1", lw=0.6, ls="--")
        ax.text(e["delay_lattice_s"] * 1e3, -5 - 6 * (i % 4), f" {_label(e)}{_fit_text(e)}", fontsize=7, color="C1")
    for th in table["thresholds_db"]:
        ax.axhline(th, color="0.7", lw=0.5)
    ax.set_ylim(-90, 0)
    ax.set_xlabel("t (ms)")
    ax.set_ylabel("echo envelope (dB re transmit peak)")
    ax.set_title("A-scan, echoes labelled by their image-source delays (lattice group velocity)")
    return plots.save(fig, path)
