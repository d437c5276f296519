"""A scene at another resolution: cell and step counts scale, metres and seconds stay
(`scale_scene_data` on the file's tables, `scene_data_at` for a target cells-per-wavelength,
`Scene.at_resolution` on a parsed scene). Per-cell weights and lags of a line are resampled
along it; a 3-D disc's per-ring weights and lags are kept (its rings are in metres)."""

from __future__ import annotations

import copy

import numpy as np

from ..lattice.kinds import KINDS
from .common import SceneError


def _c_max(data: dict) -> float:
    """Speed of the fastest fluid in a scene dict, m/s (what the grid is scaled to)."""
    from ..lattice.medium import air, material

    med = data.get("medium", {})
    bg_name = med.get("background", "air")
    bg = air(med.get("temperature_c", 20.0)) if bg_name == "air" else material(bg_name)
    speeds = [bg.speed_m_s]
    if med.get("boundary_model", "conservative") != "speed_zero":
        for o in data.get("objects", []):
            m = material(o.get("material", "rigid"))
            if m.kind == "fluid":
                speeds.append(m.speed_m_s)
    return max(speeds)


def _resample(values, n: int) -> list[float]:
    v = np.asarray(values, dtype=float)
    if len(v) == n:
        return v.tolist()
    if len(v) == 1:
        return [float(v[0])] * n
    return np.interp(np.linspace(0, 1, n), np.linspace(0, 1, len(v)), v).tolist()


def scale_scene_data(data: dict, scale: float) -> dict:
    """A copy of a parsed scene dict with the grid `scale` times as fine (physical sizes kept).

    cells_per_wavelength, a grid shape in cells, transducer n_cells, per-cell weights and lags
    (resampled along the line), edge thickness, far-field gap, snapshot interval, show_steps and
    n_steps all scale; sizes and positions in metres, duration_s and show_times_s stay. scale = 1 returns an unchanged copy.
    """
    if not scale > 0:
        raise ValueError(f"scale = {scale} must be > 0")
    d = copy.deepcopy(data)
    if scale == 1:
        return d

    def sc(n, lo=1):
        return max(lo, int(round(n * scale)))

    g = d.setdefault("grid", {})
    cpw0 = g.get("cells_per_wavelength", 20.0)
    g["cells_per_wavelength"] = cpw0 * scale
    if g.get("shape") is not None:
        g["shape"] = [sc(n, 3) for n in g["shape"]]
    e = d.setdefault("edges", {})
    e["thickness_cells"] = sc(e.get("thickness_cells", 20), 4)
    dx = _c_max(d) / (g["frequency_hz"] * g["cells_per_wavelength"])
    for t in d.get("transducers", []):
        if t.get("n_cells") is not None:
            t["n_cells"] = sc(t["n_cells"])
            n = t["n_cells"]
        elif t.get("diameter_m") is not None:
            n = max(1, int(round(t["diameter_m"] / dx)))
        else:
            n = None
        for key in ("weights", "lags_s"):
            if t.get(key) is not None and n is not None:
                t[key] = _resample(t[key], n)
    o = d.get("output", {})
    if o.get("show_steps"):
        o["show_steps"] = [sc(v) for v in o["show_steps"]]
    s = d.get("sensors", {})
    if s.get("snapshot_every_steps") is not None:
        s["snapshot_every_steps"] = sc(s["snapshot_every_steps"])
    if "farfield" in d and d["farfield"].get("gap_cells") is not None:
        d["farfield"]["gap_cells"] = sc(d["farfield"]["gap_cells"])
    elif "farfield" in d:
        d["farfield"]["gap_cells"] = sc(4)
    r = d.get("run", {})
    if r.get("n_steps") is not None:
        r["n_steps"] = sc(r["n_steps"])
    return d


def scene_data_at(data: dict, cells_per_wavelength: float) -> dict:
    """Scene tables at another resolution (`scale_scene_data`: cell and step counts
    scale, metres and seconds stay), keeping a 3-D disc's per-ring weights and lags (its rings
    are in metres, not cells)."""
    cpw0 = float((data.get("grid") or {}).get("cells_per_wavelength", 20.0))
    if not cells_per_wavelength > 0:
        raise SceneError(f"cells_per_wavelength = {cells_per_wavelength}: give a resolution > 0")
    out = scale_scene_data(data, cells_per_wavelength / cpw0)
    out["grid"]["cells_per_wavelength"] = float(cells_per_wavelength)
    kind = (data.get("grid") or {}).get("kind")
    if isinstance(kind, str) and kind in KINDS and KINDS[kind].ndim == 3:
        for t_new, t_old in zip(out.get("transducers", []), data.get("transducers", [])):
            for key in ("weights", "lags_s"):
                if key in t_old:
                    t_new[key] = copy.deepcopy(t_old[key])
    return out
