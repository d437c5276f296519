"""Each surface's own echo, isolated by a difference of runs, and its arrival against its
image-source delay (`difflattice simulate SCENE --isolate-echoes`).

In one A-scan a surface's first echo overlaps other paths (a post's with the side walls', two
walls at one range), so its envelope peak is not its own. Here the scene is run once as it is and
once without each surface, on the same lattice with the same transducer; the difference of the two
A-scans is that surface's scattered field (its interactions with the rest included, later). An
object is removed from `[[objects]]`; a rigid window side (a wall) is moved out: the window
grown on that side by the absorbing layer's depth plus half a burst, the side made absorbing
(the scene's absorbing kind; the grown cells lie beyond the wall, so the layer's own weak echo
comes a burst later). The difference contains what the surface adds: its echo and, by
construction, its interactions with the rest (double bounces, shadowing), which the image-source
delay does not model. The run without a surface stops a burst after the last step its measures
read (the fit's window, or the model echo's spread on the lattice): a side wall's costs a sixth
of the scene's steps; the isolated echo is zero after it (`recorded_until_s`).

**The arrival measure** is the peak of the Hilbert envelope of the matched-filtered echo (the
isolated echo cross-correlated with the drive burst), refined by a parabola through its
neighbours, as a lag. For a tone burst the envelope carries the time of flight (its carrier
phase moves at the phase velocity, its envelope at the group velocity, and they differ on the
lattice); the matched filter weights the band by the burst's own spectrum squared (the
estimate least disturbed by the band's edges) and gives a smooth single peak 16 periods wide
whose maximum a three-point parabola places to ~1e-4 sample. An onset (threshold crossing) would
move with the echo's level and with the dispersive precursor. "Within 0.1 period" for an
8-cycle burst is then 1/80 of the burst's length: a statement about the envelope's centre,
which the isolated echo (no overlap, float32 rounding the only noise) supports.

**The reference** is the same estimator applied to the model echo: the drive burst carried along
the round trip(s) frequency by frequency with the lattice's dispersion relation along the path
(`analytic3d.lattice_wavenumber_3d`: its group delay and the spread over the band), or with the
air's speed. The paths are the image-source / nearest-point round trip from the transducer's
centre (the weighted mean of its cells) and those via its image in each mirror (`echoes3d.mirror_paths`:
the rigid window sides, a floor under it, and the objects' planar faces) within a burst of it,
and, between a rigid floor and ceiling (`echoes3d.find_guides`), via every image of the
transducer in the pair, each weighted by the disc's directivity out and in at each frequency of
the band (`echoes3d.weighted_paths`). A corner path shadowed geometrically but within its first
Fresnel zone (`echoes3d.shadowed_paths`) is a predicted arrival of its own for the fit. The
surface is the rasterised one: the cells whose centre lies inside (hard rasterisation) present
their faces, so the distance is taken to those faces, the mean
over the rays to the surface's first Fresnel zone (exact for a plane along the cells' faces).
Times of flight: the soft source adds v(n dt) to the pressure of step n, i.e. the forcing of the
leapfrog's step n - 1 -> n, centred at (n - 1) dt, so the radiated wave leads the drive by one
step; the lag L of the matched filter (the A-scan's sample i at (i + 1) dt, the reference v(t_i))
is the time of flight (L + 1) dt.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from . import echoes3d

ESTIMATORS = ("fit", "matched", "envelope")
"""The arrival measures: the first of the copies of the model echo fitted to the isolated echo
(`observe.arrivals`), the matched-filtered echo's envelope peak, or the echo's own."""
PRIMARY = "fit"
"""The one the table's top-level fields give (the others under `by_estimator`)."""

ARRIVAL = (
    "the first significant arrival of a sum of delayed, scaled (complex amplitude: free phase) copies of the model "
    "echo fitted to the isolated echo from half a burst before its lattice delay to two bursts after (up to three "
    "for a narrow-band model echo that holds too few independent samples in two) (observe.arrivals: the first "
    "copy started at the lattice delay, more added while the BIC falls), as a time "
    "of flight with its standard error and whether it is separable from the arrivals behind it; by_estimator "
    "also gives the peak of the Hilbert envelope of the isolated echo matched-filtered with the drive burst "
    "(matched) and of the echo itself (envelope)"
)


# ------------------------------------------------------------------------------------------
# the matched filter and the model


def _spectra(ref: np.ndarray, n: int) -> tuple[int, np.ndarray]:
    n_fft = 1 << int(math.ceil(math.log2(2 * n)))
    return n_fft, np.fft.rfft(ref, n_fft)


def _ref_centre(ref: np.ndarray) -> float:
    """Where the reference's own envelope peaks (samples): the zero of the raw envelope's lag."""
    k, _, _ = echoes3d._peak(echoes3d.envelope(np.concatenate([ref, np.zeros_like(ref)])), 1, 2 * len(ref) - 1)
    return k


def arrival_lag(x: np.ndarray, ref: np.ndarray, lo: float, hi: float, *, matched: bool = True) -> tuple[float, float]:
    """(lag in samples, envelope value) of the peak of the Hilbert envelope of `x` matched-filtered
    with `ref` (`matched`), or of `x` itself less the reference's own envelope centre, within
    lags [lo, hi); parabolic refinement."""
    n_fft, r = _spectra(ref, len(x))
    spec = np.fft.rfft(x, n_fft)
    y = np.fft.irfft(spec * np.conj(r) if matched else spec, n_fft)
    zero = 0.0 if matched else _ref_centre(ref)
    k, v, _ = echoes3d._peak(echoes3d.envelope(y), int(math.floor(lo + zero)), int(math.ceil(hi + zero)))
    return k - zero, v


def model_lag_steps(
    grid, ref: np.ndarray, n: int, paths_m, weights, direction, *, lattice: bool, matched: bool = True
) -> float:
    """`arrival_lag` (steps) of the model echo: `ref` carried along `paths_m` (summed with
    `weights`) with the lattice's dispersion relation along `direction`, or the air's speed."""
    n_fft, r = _spectra(ref, n)
    w = 2 * np.pi * np.fft.rfftfreq(n_fft)  # rad/step
    keep = np.abs(r) > 1e-6 * np.abs(r).max()
    keep[0] = False
    phase = echoes3d.path_phase(grid, w, keep, paths_m, weights, direction, lattice=lattice)
    y = np.fft.irfft(np.where(keep, (np.abs(r) ** 2 if matched else r) * phase, 0.0), n_fft)
    zero = 0.0 if matched else _ref_centre(ref)
    guess = min(paths_m) / grid.dx_m / grid.courant + zero
    k, _, _ = echoes3d._peak(echoes3d.envelope(y), int(guess - 4 * len(ref)), int(guess + 4 * len(ref)))
    return k - zero


def rasterised_offset_m(surface: dict, occupied, centre_m, grid, wavelength_m: float) -> float:
    """How much farther (m, one way) the rasterised surface lies than the true one, seen from
    `centre_m`: the mean, over rays to points of the surface's first Fresnel zone round its nearest
    point, of where the ray enters a cell `occupied` (cell centres -> bool) minus where it meets
    the true surface."""
    c = np.asarray(centre_m, float)
    p0 = np.asarray(surface["point_m"], float)
    u = np.asarray(surface["direction"], float)
    d = surface["distance_m"]
    e1 = np.cross(u, [0.0, 0.0, 1.0] if abs(u[2]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    rho = math.sqrt(0.5 * wavelength_m * d)  # first Fresnel zone of the round trip
    dx = grid.dx_m
    offsets = []
    for a in np.linspace(-rho, rho, 9):
        for b in np.linspace(-rho, rho, 9):
            if a * a + b * b > rho * rho:
                continue
            q = surface["nearest"](p0 + a * e1 + b * e2)
            if np.linalg.norm(q - (p0 + a * e1 + b * e2)) > rho:  # projected far away: off the surface
                continue
            ray = q - c
            s0 = float(np.linalg.norm(ray))
            ray /= s0

            def inside(s, ray=ray):
                return occupied(np.rint((c[None, :] + s[:, None] * ray[None, :]) / dx) * dx)

            s = s0 + np.arange(-1.5 * dx, 1.5 * dx, dx / 16)
            hit = np.flatnonzero(inside(s))
            if len(hit) and hit[0] > 0:
                lo, hi = float(s[hit[0] - 1]), float(s[hit[0]])
                for _ in range(20):  # bisect the entry to dx / 16 / 2^20
                    mid = 0.5 * (lo + hi)
                    lo, hi = (lo, mid) if inside(np.array([mid]))[0] else (mid, hi)
                offsets.append(hi - s0)
    return float(np.mean(offsets)) if offsets else 0.0


# ------------------------------------------------------------------------------------------
# the scene without one surface

_POINTS = ("centre_m", "lo_m", "hi_m", "point_m")


def _shift_object(o, axis: int, metres: float):
    def moved(v):
        return None if v is None else tuple(float(x) + (metres if i == axis else 0.0) for i, x in enumerate(v))

    if getattr(o, "shape", "") == "mesh":
        raise ValueError("a mesh object cannot be moved to grow the window on a low side; isolate high sides only")
    changes: dict[str, Any] = {f: moved(getattr(o, f)) for f in _POINTS if hasattr(o, f)}
    if hasattr(o, "parts"):
        changes["parts"] = tuple(_shift_object(p, axis, metres) for p in o.parts)
    return dataclasses.replace(o, **changes)


def _shifted(scene, axis: int, metres: float):
    """The scene with every position moved `metres` along `axis` (to grow its window on a low side)."""

    def moved(v):
        return tuple(float(x) + (metres if i == axis else 0.0) for i, x in enumerate(v))

    s = scene.sensors
    slices = s.snapshot_slices_m
    if slices is not None:
        slices = tuple((a, float(p) + (metres if "xyz".index(str(a)) == axis else 0.0)) for a, p in slices)
    return dataclasses.replace(
        scene,
        transducers=tuple(dataclasses.replace(t, centre_m=moved(t.centre_m)) for t in scene.transducers),
        objects=tuple(_shift_object(o, axis, metres) for o in scene.objects),
        sensors=dataclasses.replace(s, probes_m=tuple(moved(p) for p in s.probes_m), snapshot_slices_m=slices),
    )


def without(scene, grid, surface: dict, cycles: float, *, n_steps: int | None = None):
    """The scene without `surface` (a row of `echoes3d.surfaces`), on the same lattice: an object
    left out, or a rigid window side moved out (the window grown on that side by the absorbing
    layer's depth and half a burst, the side absorbing; a low side grown by moving everything);
    run for `n_steps` (default: as long as the scene)."""
    if n_steps is not None:
        scene = dataclasses.replace(scene, run=dataclasses.replace(scene.run, n_steps=int(n_steps), duration_s=None))
    if "object" in surface:
        i = surface["object"]
        return dataclasses.replace(scene, objects=scene.objects[:i] + scene.objects[i + 1 :])
    key = surface["side"]
    axis = "xyz".index(key[0])
    ed = scene.edges
    sides = ("x_lo", "x_hi", "y_lo", "y_hi", "z_lo", "z_hi")
    absorbing = {getattr(ed, k) or ed.kind for k in sides} & {"pml", "mur", "sponge"}
    kind = next(iter(absorbing)) if absorbing else "sponge"
    depth = ed.thickness_cells if kind != "mur" else 0
    grow = depth + int(math.ceil(0.5 * cycles * grid.cells_per_wavelength)) + 2
    shape = list(grid.shape)
    shape[axis] += grow
    edges = dataclasses.replace(ed, **{key: kind})
    out = dataclasses.replace(scene, grid=dataclasses.replace(scene.grid, size_m=None, shape=tuple(shape)), edges=edges)
    return _shifted(out, axis, grow * grid.dx_m) if key.endswith("lo") else out


def _occupied(scene, grid, surface: dict, shift_m=None):
    """Cell centres (..., 3) m -> inside the surface's solid (hard rasterisation: centre inside)."""
    if "object" in surface:
        import jax.numpy as jnp

        from ..scene.objects import shape3d

        i = surface["object"]
        shape = shape3d(scene.path, f"objects[{i}]", scene.objects[i])
        return lambda x: np.asarray(shape.sdf(*(jnp.asarray(x[:, k]) for k in range(3)))) < 0
    axis = "xyz".index(surface["side"][0])
    n = grid.shape[axis]
    if surface["side"].endswith("lo"):
        return lambda x: np.rint(x[:, axis] / grid.dx_m) < 0
    return lambda x: np.rint(x[:, axis] / grid.dx_m) > n - 1


# ------------------------------------------------------------------------------------------
# the runs and the table


def _receiver(sr) -> tuple[Any, np.ndarray, np.ndarray, np.ndarray]:
    """(receiver, t_s, A-scan, the transducer's centre in m: the weighted mean of its cells)."""
    r = sr.built.receivers[0]
    t, a = sr.a_scans[r.name]
    src = sr.built.sources[r.source]
    centre = np.average(np.asarray(src.cells_array, float), axis=0, weights=np.abs(np.asarray(src.weights)))
    return r, np.asarray(t, float), np.asarray(a, float), centre * sr.grid.dx_m


def _measure(echo, ref, model, dt: float, f0: float, burst_steps: float, *, matched: bool) -> dict[str, Any]:
    """One estimator's arrival (time of flight: the lag + the soft source's one-step lead) of the
    isolated echo, searched within half a burst of the model's lattice delay, against the model's
    lattice and air delays (same estimator)."""
    lag_lat = model(lattice=True, matched=matched)
    lag_air = model(lattice=False, matched=matched)
    lag, _ = arrival_lag(echo, ref, lag_lat - 1 - 0.5 * burst_steps, lag_lat - 1 + 0.5 * burst_steps, matched=matched)
    arrival = (lag + 1) * dt
    return {
        "delay_lattice_s": lag_lat * dt,
        "delay_air_s": lag_air * dt,
        "arrival_s": arrival,
        "error_periods": (lag + 1 - lag_lat) * dt * f0,
        "error_periods_air": (lag + 1 - lag_air) * dt * f0,
        "resolved": bool(abs(lag + 1 - lag_lat) < 0.5 * burst_steps - 1),
    }


def measure_echo(grid, echo, ref, model, template, burst_steps: float, others_steps=()) -> dict[str, dict]:
    """Every estimator's arrival (`ESTIMATORS`) of one isolated echo against its lattice delay
    (`template`: the model echo on the echo's samples, `echoes3d.model_echo`, the fit's pulse;
    `others_steps`: further predicted arrivals, steps after it, where the fit starts copies)."""
    dt, f0 = grid.dt_s, grid.frequency_hz
    got = {m: _measure(echo, ref, model, dt, f0, burst_steps, matched=m == "matched") for m in ESTIMATORS if m != "fit"}
    lag_lat = model(lattice=True, matched=True)
    lag_air = model(lattice=False, matched=True)
    fit = echoes3d.fit_first_arrival(echo, template, lag_lat, burst_steps, 1 / (f0 * dt), others_steps)
    first = fit.first_arrival
    got["fit"] = {
        "delay_lattice_s": lag_lat * dt,
        "delay_air_s": lag_air * dt,
        "arrival_s": (lag_lat + first.delay) * dt,
        "error_periods": first.delay * dt * f0,
        "error_periods_air": (lag_lat + first.delay - lag_air) * dt * f0,
        "sigma_periods": first.sigma_delay * dt * f0,
        "separable": fit.separable,
        "resolved": fit.separable,
        "why": fit.why,
        "arrivals_periods": [a.delay * dt * f0 for a in fit.arrivals],
        "arrivals_relative_amplitude": [abs(a.amplitude) / abs(first.amplitude) for a in fit.arrivals],
        "residual_rel": fit.residual_rel,
    }
    return {m: got[m] for m in ESTIMATORS}


def surface_names(scene) -> list[str]:
    """The names a 3-D scene's surfaces can have in echoes.json, from the file alone (no build):
    each object's (its name, else "SHAPE i") and "wall SIDE" for each rigid window side (one that
    passes by the transducer or lies behind an object has no echo of its own and is left out
    later, by `echoes3d.surfaces`)."""
    names = [str(o.name or f"{o.shape} {i}") for i, o in enumerate(scene.objects)]
    return names + [f"wall {k}" for k in echoes3d.SIDES if echoes3d._side_kind(scene, k) == "rigid"]


def _on_mirrors(scene, grid, centre_m) -> np.ndarray:
    """The transducer's centre put on each rigid window side that passes within its radius: such a
    side is a symmetry plane (the cells on this side of it and their mirror images make the disc)."""
    c = np.array(centre_m, float)
    radius = 0.5 * float(scene.transducers[0].diameter_m or 0.0)
    for axis, n in enumerate(grid.shape):
        for side, plane in (("lo", -0.5 * grid.dx_m), ("hi", (n - 0.5) * grid.dx_m)):
            rigid = (getattr(scene.edges, f"{'xyz'[axis]}_{side}") or scene.edges.kind) == "rigid"
            if rigid and abs(c[axis] - plane) <= radius:
                c[axis] = plane
    return c


def _check_pulse_echo(scene) -> float:
    """The drive's cycles; refuses a scene that is not a 3-D pulse-echo run of a tone burst."""
    from ..scene.model import SceneError

    if scene.kind.ndim != 3:
        raise SceneError(f'{scene.path}: --isolate-echoes is for kind = "3d" pulse-echo scenes')
    t = scene.transducers[0] if scene.transducers else None
    if t is None or t.signal != "burst" or not getattr(t, "receive", False):
        raise SceneError(
            f"{scene.path}: [transducers[0]]: --isolate-echoes needs a receiving transducer driven by a tone "
            'burst (signal = "burst", receive = true)'
        )
    return float(t.cycles)


def _saved(scene, path) -> tuple[Any, Any, np.ndarray, np.ndarray, np.ndarray, dict, dict]:
    """(grid, receiver, t_s, A-scan, centre m, isolated echoes by surface, their recorded steps) of a
    saved echoes_isolated.npz of `scene`, the scene built (not run) for its grid and transducer. An
    npz written before the A-scan was saved in it gives zeros for the A-scan (levels then unknown);
    one written before the runs without a surface were cut short, the whole record for each echo."""
    built = scene.build()
    r = built.receivers[0]
    src = built.sources[r.source]
    centre = np.average(np.asarray(src.cells_array, float), axis=0, weights=np.abs(np.asarray(src.weights)))
    with np.load(path) as z:
        t = np.asarray(z["t_s"], float)
        a = np.asarray(z["a_scan"], float) if "a_scan" in z else np.zeros_like(t)
        echoes = {str(k): np.asarray(v, float) for k, v in zip(z["surfaces"], z["echoes"])}
        ends = z["recorded_steps"] if "recorded_steps" in z else [len(t)] * len(echoes)
    recorded = {k: int(n) for k, n in zip(echoes, ends)}
    return built.grid, r, t, a, centre * built.grid.dx_m, echoes, recorded


def surface_paths(scene, grid, centre_m, s: dict, mirrors, guides, within_m: float) -> tuple[list, list, float]:
    """(round trips m, their weights, the rasterised offset m) of surface `s`'s model echo:
    `echoes3d.weighted_paths` within `within_m` of its direct one, each lengthened by twice the
    offset of its rasterised surface from its geometric one (`rasterised_offset_m`)."""
    wavelength = grid.dx_m * grid.cells_per_wavelength
    offset = rasterised_offset_m(s, _occupied(scene, grid, s), centre_m, grid, wavelength)
    paths, weights = echoes3d.weighted_paths(s, mirrors, within_m, scene.transducers[0], wavelength, guides)
    return [p + 2 * offset for p in paths], weights, offset


def isolate_echoes(scene, out_dir, *, full=None, only=None, saved=None, quiet: bool = True, log=None) -> dict[str, Any]:
    """Each surface's first echo isolated by a difference of runs (module docstring): the scene run
    as it is (or `full`, its `SceneRun3D` already run) and once without each surface whose echo
    comes after the transmit; its arrival against the lattice and air delays. Writes
    OUT/echoes_isolated.json, echoes_isolated.png and echoes_isolated.npz (t_s, a_scan, surfaces,
    echoes: the isolated A-scans); returns the table. `only`: the surfaces to
    isolate (names as in echoes.json; default all). `saved`: an echoes_isolated.npz of this scene
    written before: its echoes measured again, no run. `log(str)` is told of each run."""
    from ..solver.sources import ToneBurst
    from .scene3d_run import run_scene3d

    cycles = _check_pulse_echo(scene)
    say = log or (lambda s: None)
    saved_recorded: dict[str, int] = {}
    if saved is not None:
        grid, r, t, a, centre, saved_echoes, saved_recorded = _saved(scene, saved)
    else:
        sr = full if full is not None else run_scene3d(scene, quiet=quiet)
        grid = sr.grid
        r, t, a, centre = _receiver(sr)
    centre = _on_mirrors(scene, grid, centre)
    dt, f0 = grid.dt_s, grid.frequency_hz
    burst_steps = cycles / f0 / dt
    ref = np.asarray(ToneBurst(f0, cycles)(t), float)[: int(math.ceil(burst_steps)) + 2]
    transmit = echoes3d._transmit_peak(a, r.gate_start_step, burst_steps)
    wavelength = grid.dx_m * grid.cells_per_wavelength
    rows, traces, unrecorded = [], {}, []
    recorded_steps: dict[str, int] = {}
    found = echoes3d.surfaces(scene, grid, centre)
    mirrors = echoes3d.find_mirrors(scene, grid, centre, found)
    within = cycles * wavelength
    guides = echoes3d.find_guides(scene, grid, centre, echoes3d._reach(grid, within))
    if only is not None:
        unknown = set(only) - {s["surface"] for s in found}
        if unknown:
            from ..scene.model import SceneError

            raise SceneError(
                f"{scene.path}: --isolate {sorted(unknown)}: no such surface; give one of the scene's: "
                f"{[s['surface'] for s in found]}"
            )
        found = [s for s in found if s["surface"] in only]
    for s in found:
        paths, weights, offset = surface_paths(scene, grid, centre, s, mirrors, guides, within)
        model = functools.partial(model_lag_steps, grid, ref, len(a), paths, weights, s["direction"])
        if model(lattice=True) < r.gate_start_step:
            continue  # inside the transmit: no echo of its own (a floor beside the transducer)
        if model(lattice=True) - 1 + 2 * burst_steps > len(a):  # the fit's window, two bursts after its start
            say(
                f"not isolating {s['surface']!r}: its echo ends after the record (a longer [run] duration_s records it)"
            )
            unrecorded.append(s["surface"])
            continue
        if saved is not None and s["surface"] not in saved_echoes:
            continue
        template = echoes3d.model_echo(grid, ref, len(a), paths, weights, s["direction"])  # the fit's pulse
        if saved is not None:
            echo, without_shape = saved_echoes[s["surface"]], None
            recorded = saved_recorded.get(s["surface"], len(a))
        else:
            # the steps the measures read: the fit's window (up to MAX_WINDOW_BURSTS after the echo
            # starts; the matched filter and the envelope read within it), or the model echo's own
            # length (a short burst spreads on the lattice: its band reaches where the lattice's
            # group velocity falls) and a burst; the run without the surface stops there (the later
            # steps would cost time and tell nothing of its first echo)
            env = echoes3d.envelope(np.concatenate([template, np.zeros_like(template)]))[: len(a)]
            tail = float(np.flatnonzero(env > 1e-3 * env.max())[-1]) if np.any(env > 0) else 0.0
            needed = min(
                len(a),
                int(math.ceil(max(model(lattice=True) + echoes3d.MAX_WINDOW_BURSTS * burst_steps, tail + burst_steps)))
                + 2,
            )
            say(f"isolating {s['surface']!r}: the scene without it, {needed} of {len(a)} steps ...")
            sr_wo = run_scene3d(without(scene, grid, s, cycles, n_steps=needed), quiet=True)
            _, _, a_wo, _ = _receiver(sr_wo)
            recorded = min(len(a_wo), len(a))
            echo = np.zeros_like(a)  # after `recorded` no difference was measured: zeros, and the row says so
            echo[:recorded] = a[:recorded] - a_wo[:recorded]
            without_shape = list(sr_wo.grid.shape)
        # corner paths that graze an edge (shadowed within their Fresnel zone): predicted copies
        partly = echoes3d.shadowed_lags_steps(s, mirrors, grid, 2 * within)
        got = measure_echo(grid, echo, ref, model, template, burst_steps, partly)
        lo = int(got[PRIMARY]["delay_lattice_s"] / dt)
        level = float(echoes3d.envelope(echo)[lo : lo + int(2 * burst_steps)].max()) if lo < len(echo) else 0.0
        rows.append(
            {k: v for k, v in s.items() if k != "nearest"}
            | {
                "rasterised_offset_m": offset,
                "under_resolved": echoes3d.under_resolved(s, grid),
                "path_m": paths[0],
                "merged_paths_m": [float(p) for p in paths],
            }
            | got[PRIMARY]
            | {
                "level_db": 20 * math.log10(max(level, 1e-300) / transmit),
                "by_estimator": got,
                "without_shape": without_shape,
                "recorded_until_s": recorded * dt,  # the isolated echo's end (the run without it stopped)
            }
        )
        traces[s["surface"]] = echo
        recorded_steps[s["surface"]] = recorded
        if saved is None:  # a run cut short keeps the surfaces done (a saved file is not rewritten half-way)
            _write_isolated(out_dir, t, a, f0, cycles, dt, rows, traces, recorded_steps, unrecorded, complete=False)
        say(
            f"isolated {s['surface']!r}: first arrival {got[PRIMARY]['error_periods']:+.3f} ± "
            f"{got[PRIMARY]['sigma_periods']:.3f} periods vs lattice delay"
        )
    doc = _write_isolated(out_dir, t, a, f0, cycles, dt, rows, traces, recorded_steps, unrecorded, complete=True)
    out = Path(out_dir)
    plot_isolated(t, traces, doc, transmit, out / "echoes_isolated.png", recorded_steps)
    return doc


def _write_isolated(
    out_dir, t, a, f0, cycles, dt, rows, traces, recorded_steps, unrecorded, *, complete: bool
) -> dict[str, Any]:
    """Write OUT/echoes_isolated.json and .npz with the surfaces isolated so far (`complete`: all
    of them; a run cut short keeps those done, marked incomplete); returns the table."""
    doc = {
        "what": "each surface's first echo isolated by a difference of runs (the scene minus the scene without "
        "it, same lattice and transducer), its arrival against the lattice's and the air's delay of its "
        "first geometric arrival (first_arrival: the image source's round trip, or the shortest path via the "
        "nearest edge where no face has a specular point; rasterised surface; merged with the paths via the "
        "transducer's images in its mirrors within a burst: rigid window sides and planar object faces)",
        "first_arrival": echoes3d.FIRST_ARRIVAL,
        "arrival": ARRIVAL,
        "reference": "the model echo: the drive burst carried along the paths with the lattice's dispersion relation "
        "(delay_lattice_s) or the air's speed (delay_air_s), its delay read by the matched filter; the fit's "
        "error is the excess delay of the first fitted copy of the lattice model echo",
        "frequency_hz": f0,
        "burst_cycles": cycles,
        "dt_s": dt,
        "echoes": rows,
        "not_recorded": unrecorded,  # surfaces whose echo ends after the record: not isolated
        "complete": complete,  # false while surfaces remain (a run cut short keeps those done)
    }
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "echoes_isolated.json").write_text(json.dumps(doc, indent=1, default=float))
    np.savez_compressed(  # the isolated echoes themselves, to measure again without running
        out / "echoes_isolated.npz",
        t_s=t,
        a_scan=a,
        surfaces=np.array(list(traces)),
        echoes=np.array(list(traces.values())),
        recorded_steps=np.array([recorded_steps[k] for k in traces], dtype=np.int64),  # each echo's end: zeros after
    )
    return doc


def plot_isolated(t_s, traces: dict, doc: dict, transmit: float, path, recorded_steps=None):
    """Left: each isolated echo's envelope (dB re the transmit peak) up to where it was recorded,
    its lattice delay dashed; right: each arrival's error in periods against the lattice delay, the
    +-0.1 period band shaded."""
    from matplotlib.figure import Figure

    from .. import plots

    fig = Figure(figsize=(11, 4))
    ax, bx = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    t_ms = np.asarray(t_s) * 1e3
    rows = doc["echoes"]
    for i, e in enumerate(rows):
        x = traces[e["surface"]]
        env = echoes3d.envelope(np.concatenate([x, np.zeros_like(x)]))[: len(x)]  # padded: no wrap-around
        end = (recorded_steps or {}).get(e["surface"], len(x))
        level = 20 * np.log10(np.maximum(env[:end] / transmit, 1e-6))
        ax.plot(t_ms[:end], level, lw=0.8, color=f"C{i}", label=echoes3d._label(e))
        ax.axvline(e["delay_lattice_s"] * 1e3, color=f"C{i}", lw=0.6, ls="--")  # time of flight: the echo starts
    ax.set_ylim(-100, 0)
    ax.set_xlabel("t (ms)")
    ax.set_ylabel("isolated echo envelope (dB re transmit peak)")
    ax.legend(fontsize=7)
    ax.set_title("each surface's echo: the scene minus the scene without it", fontsize=9)
    bx.axvspan(-0.1, 0.1, color="0.9")
    y = np.arange(len(rows))
    sigma = [e.get("sigma_periods", 0.0) for e in rows]  # the fit's standard error (the primary measure)
    bx.errorbar([e["error_periods"] for e in rows], y, xerr=sigma, fmt="o", label="vs lattice delay")
    bx.set_yticks(y, [echoes3d._label(e) for e in rows], fontsize=7)
    bx.axvline(0, color="0.5", lw=0.5)
    bx.set_xlabel("arrival - lattice delay (periods)")
    bx.set_title("first arrival (fit, ±1 standard error) vs image-source delay", fontsize=9)
    fig.tight_layout()
    return plots.save(fig, path)
