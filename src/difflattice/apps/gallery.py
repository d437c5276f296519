"""The paper's gallery: render every ``data/scenes/fig*.toml`` into images and an index page.

`render_gallery(out_dir)` loads each scene file, optionally shrinks the grid (``scale`` multiplies
the cells per wavelength and keeps every physical size, so 0.25 gives 5 cells per wavelength: a
quick, coarse look), runs it with `scene_run.run_scene`, writes the usual outputs with
`scene_run.write_outputs` into ``out_dir/<name>/`` (below scale 1, a quick look: no animation and no
per-snapshot frames), and adds:

- ``<name>/figure.png``: the field at the moment(s) the paper shows (the scene file's
  ``[output] show_steps``, else the last step), one panel per moment, ``PANEL_PX`` pixels wide
  each (see `figure_size_px`);
- ``<name>/wavefront.png`` for scenes recording arrival times at probes (Fig. 3);
- ``compare_*.png`` for the figures the paper compares (`COMPARISONS`: Figs. 4, 7, 8, 9);
- ``index.md`` (a Markdown page: each figure's image and what the paper shows, taken from the
  comment block at the top of its scene file) and ``gallery.json`` (per scene: steps, wall
  times, files, relative to ``out_dir``).

The scene files live in the repository's ``data/scenes`` and are installed with the package
(``difflattice/scenes``); pass ``scenes_dir`` to render other files.
"""

from __future__ import annotations

import json
import re
import time
import tomllib
import warnings
from pathlib import Path

import numpy as np


def _default_scenes_dir() -> Path:
    """The repository's data/scenes when running from a checkout, else the copy installed with
    the package (difflattice/scenes: in the repository a symlink to data/scenes, packaged as
    package data)."""
    package = Path(__file__).resolve().parents[1]  # src/difflattice
    repo = package.parents[1] / "data" / "scenes"
    return repo if repo.is_dir() else package / "scenes"


DEFAULT_SCENES_DIR = _default_scenes_dir()

# Figures the paper compares. kind "probe": probe 0's signal of each scene on one plot (from
# `start_step`, in scene-file steps); kind "beam": peak |p| on an arc `radius_m` from the first
# transducer's centre, in dB re the largest.
COMPARISONS: dict[str, dict] = {
    "fig04": {
        "scenes": ("fig04a_wall_speed_zero", "fig04b_wall_rigid"),
        "kind": "probe",
        "start_step": 0,
        "title": "Fig. 4: echo on the reflected path (speed zero: phase reversed; rigid: not)",
    },
    "fig07": {
        "scenes": ("fig07a_convex_edge_sharp", "fig07b_convex_edge_rounded"),
        "kind": "probe",
        "start_step": 1000,
        "title": "Fig. 7: echo back at the transducer (sharp vs rounded edge)",
    },
    "fig08": {
        "scenes": ("fig08_stepped_wall",),
        "kind": "probe",
        "start_step": 1000,
        "title": "Fig. 8: the two echoes of the stepped wall at the transducer",
    },
    "fig09": {
        "scenes": ("fig09_cone_horn", "fig09_no_horn"),
        "kind": "beam",
        "radius_m": 0.2,
        "angles_deg": (-30.0, 30.0, 0.5),
        "title": "Fig. 9: beam 200 mm from the face, with and without the 5-degree horn",
    },
}

PANEL_PX = 600
"""Width of one field panel of figure.png, pixels."""
MARGIN_PX = 105
"""Height added to a panel for the title and the axis labels, pixels."""
FIG_DPI = 100


def figure_size_px(grid_shape, n_panels: int) -> tuple[int, int]:
    """(width, height) in pixels of a scene's figure.png: `n_panels` panels side by side, each
    PANEL_PX wide and PANEL_PX * ny / nx + MARGIN_PX high."""
    nx, ny = grid_shape
    return n_panels * PANEL_PX, int(round(PANEL_PX * ny / nx)) + MARGIN_PX


def scene_files(scenes_dir: str | Path | None = None) -> list[Path]:
    """The gallery's scene files (``fig*.toml``), sorted by name."""
    d = Path(scenes_dir) if scenes_dir is not None else DEFAULT_SCENES_DIR
    if not d.is_dir():
        raise FileNotFoundError(f"scene directory {d} not found: pass scenes_dir (the repository's data/scenes)")
    return sorted(d.glob("fig*.toml"))


def scene_description(path: str | Path) -> list[str]:
    """The comment block at the top of a scene file, one string per line (without '# ')."""
    lines = []
    for line in Path(path).read_text().splitlines():
        s = line.strip()
        if not s.startswith("#"):
            break
        lines.append(s[1:].strip())
    return lines


def describe_scene(path: str | Path) -> dict:
    """The top comment block split into ``title`` (its first sentence), ``paper`` (what the
    paper shows: the text before "Here:") and ``scene`` (how the file models it: from "Here:")."""
    text = " ".join(scene_description(path)).strip()
    head, _, ours = text.partition("Here:")
    # the first full stop that ends a sentence (not "Fig. 6" or "eq. 10")
    parts = re.split(r"(?<!Fig)(?<!Figs)(?<!eq)\.\s+(?=[A-Z0-9(])", head.strip(), maxsplit=1)
    if len(parts) > 1:
        parts[0] += "."
    title = parts[0] if parts and parts[0] else Path(path).stem
    paper = parts[1] if len(parts) > 1 else ""
    return {"title": title, "paper": paper.strip(), "scene": ("Here: " + ours.strip()) if ours else ""}


# ------------------------------------------------------------------------------------------
# scaling


def load_scaled_scene(path: str | Path, scale: float = 1.0):
    """Read a scene file into a `Scene` with its grid `scale` times as fine (`Scene.scaled`)."""
    from ..scene.model import load_scene

    return load_scene(path).scaled(scale)


# ------------------------------------------------------------------------------------------
# pictures


def _pick_frames(sr, wanted_steps):
    """(field, step) pairs for the wanted steps: the field kept at that moment (`[output]
    show_steps`), else the final field."""
    n = sr.summary["run"]["n_steps"]
    out = []
    for w in wanted_steps:
        if w in sr.moments:
            out.append((np.asarray(sr.moments[w]), int(w)))
        else:
            out.append((np.asarray(sr.result.final.pressure), n))
    return out


def write_figure(sr, path: Path, wanted_steps, *, title: str = "") -> Path:
    """figure.png: one field panel per wanted step, at the size `figure_size_px` gives."""
    from matplotlib.figure import Figure  # not pyplot: no backend chosen, no global figure list

    from .. import plots

    g = sr.grid
    frames = _pick_frames(sr, wanted_steps)
    w, h = figure_size_px(g.shape, len(frames))
    fig = Figure(figsize=(w / FIG_DPI, h / FIG_DPI), dpi=FIG_DPI)
    from .scene_run import obstacle_map

    obst = obstacle_map(sr.stepper)
    src = [s.cells_array for s in sr.stepper.sources]
    probes = np.asarray(sr.stepper.sensors.probes).reshape(-1, 2)
    every = sr.render_every
    top = 1 - 55 / h
    bottom = 48 / h
    for i, (f, s) in enumerate(frames):
        left = (i * PANEL_PX + 60) / w
        width = (PANEL_PX - 75) / w
        ax = fig.add_axes((left, bottom, width, top - bottom))
        plots.field_image(f, g.dx_m, every=every, step=s, dt_s=g.dt_s, obstacles=obst, sources=src, ax=ax)
        if len(probes):
            ax.plot(probes[:, 0] * g.dx_m * 1e3, probes[:, 1] * g.dx_m * 1e3, "+", color="tab:cyan", ms=5)
        ax.set_aspect("auto")
    if title:
        fig.suptitle(title, fontsize=10, y=1 - 5 / h, va="top")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=FIG_DPI)
    return path


def write_wavefront(sr, path: Path) -> Path | None:
    """For a scene with arrival times and probes (Fig. 3): the front's lag behind its earliest
    point along the probe line, in mm of travel, against lateral position."""
    from .. import plots

    res, st, g = sr.result, sr.stepper, sr.grid
    probes = np.asarray(st.sensors.probes).reshape(-1, 2)
    if res.arrival is None or len(probes) < 2:
        return None
    arr = np.asarray(res.arrival)[probes[:, 0], probes[:, 1]].astype(float)
    arr[arr < 0] = np.nan
    if np.all(np.isnan(arr)):
        return None
    lag_mm = (arr - np.nanmin(arr)) * g.dt_s * g.c_max_m_s * 1e3
    # lateral coordinate: along the face of the first transducer
    c = st.sources[0].cells_array
    along = c[-1] - c[0]
    along = along / max(np.hypot(*along), 1e-12)
    centre = c.mean(0)
    lateral = ((probes - centre) @ along) * g.dx_m
    fig = plots.wavefront_plot(
        lateral,
        {"model (first arrival above threshold)": (lag_mm, "o-")},
        ylabel="front behind its leading point (mm)",
        title="wavefront along the probe line",
    )
    ax = fig.axes[0]
    ax.invert_yaxis()
    return plots.save(fig, path)


def _read_run(out_dir: Path, name: str):
    d = out_dir / name
    if not (d / "sensors.npz").exists() or not (d / "summary.json").exists():
        return None
    return np.load(d / "sensors.npz"), json.loads((d / "summary.json").read_text())


def write_comparison(out_dir: Path, key: str, spec: dict, scale: float) -> Path | None:
    """compare_<key>.png from the scenes' sensors.npz (None if a scene was not rendered)."""
    from matplotlib.figure import Figure  # not pyplot: no backend chosen, no global figure list

    runs = {n: _read_run(out_dir, n) for n in spec["scenes"]}
    if any(v is None for v in runs.values()):
        return None
    if len({summ["grid"]["cells_per_wavelength"] for _, summ in runs.values()}) > 1:
        return None  # left over from renders at different scales
    fig = Figure(figsize=(8, 4))
    ax = fig.subplots()
    if spec["kind"] == "probe":
        for n, (npz, summ) in runs.items():
            if "probes_pa" not in npz:
                return None
            p = npz["probes_pa"][:, 0]
            dt = summ["grid"]["dt_s"]
            k0 = int(round(spec["start_step"] * scale))
            t = (np.arange(len(p)) + 1) * dt * 1e6
            ax.plot(t[k0:], p[k0:], label=n)
        ax.set_xlabel("time (µs)")
        ax.set_ylabel("pressure at probe 0 (Pa)")
    else:
        a0, a1, da = spec["angles_deg"]
        angles = np.arange(a0, a1 + da / 2, da)
        curves = {}
        for n, (npz, summ) in runs.items():
            pm = npz["p_max_pa"]
            dx = summ["grid"]["dx_m"]
            data = tomllib.loads(Path(summ["scene"]).read_text()) if Path(summ["scene"]).exists() else {}
            c0 = np.asarray(data.get("transducers", [{}])[0].get("centre_m", [0, pm.shape[1] * dx / 2]))
            th = np.radians(angles)
            pts = c0[None] + spec["radius_m"] * np.stack([np.cos(th), np.sin(th)], 1)
            ij = np.clip(np.rint(pts / dx).astype(int), 0, np.array(pm.shape) - 1)
            curves[n] = pm[ij[:, 0], ij[:, 1]]
        ref = max(float(v.max()) for v in curves.values()) or 1.0
        for n, v in curves.items():
            ax.plot(angles, 20 * np.log10(np.maximum(v / ref, 1e-5)), label=n)
        ax.set_xlabel("angle from the axis (deg)")
        ax.set_ylabel("peak level (dB re largest)")
        ax.set_ylim(-40, 2)
    ax.set_title(spec["title"], fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = out_dir / f"compare_{key}.png"
    fig.savefig(path, dpi=FIG_DPI)
    return path


# ------------------------------------------------------------------------------------------
# the gallery


def _select(files: list[Path], names) -> list[Path]:
    if not names:
        return files
    chosen = []
    for n in names:
        hits = [f for f in files if f.stem == n] or [f for f in files if f.stem.startswith(n)]
        if not hits:
            raise FileNotFoundError(f"no gallery scene named {n!r}; known: {', '.join(f.stem for f in files)}")
        chosen += [f for f in hits if f not in chosen]
    return sorted(chosen)


def render_scene(
    path: str | Path, out_dir: str | Path, *, scale: float = 1.0, progress: bool = True, animate: bool | None = None
) -> dict:
    """Render one scene file into ``out_dir`` (its own folder); returns its gallery entry with
    file paths relative to ``out_dir``'s parent."""
    from ..lattice.medium import ResolutionWarning
    from ..scene.model import SceneError
    from .scene_run import SceneRun, run_scene, write_outputs

    path, out = Path(path), Path(out_dir)
    name = path.stem
    t0 = time.perf_counter()
    scene = load_scaled_scene(path, scale)
    with warnings.catch_warnings():
        if scale < 1:  # a deliberately coarse preview (its label says so): no resolution warnings
            warnings.simplefilter("ignore", ResolutionWarning)
        sr = run_scene(scene, progress=progress)
    if not isinstance(sr, SceneRun):  # the gallery's figures are plane and rz scenes
        raise SceneError(f"{path}: the gallery renders plane and rz scenes; run a 3-D scene with difflattice simulate")
    t_sim = time.perf_counter() - t0
    wanted = sorted(sr.moments) or [sr.summary["run"]["n_steps"]]
    quick = scale < 1
    # a quick look writes no per-snapshot frames (PNG frames dominate the time at small scales)
    files = write_outputs(
        sr,
        out,
        frames=False if quick else None,
        animation=("none" if quick else None) if animate is None else (None if animate else "none"),
    )
    desc = describe_scene(path)
    short = desc["title"].split(":")[0] if ":" in desc["title"] else ""
    label = f"{short}: {name}" if short else name
    if scale != 1:
        label += f" (scale {scale:g}: {sr.grid.cells_per_wavelength:g} cells per wavelength)"
    files["figure"] = str(write_figure(sr, out / "figure.png", wanted, title=label))
    wf = write_wavefront(sr, out / "wavefront.png")
    if wf is not None:
        files["wavefront"] = str(wf)
    frames = _pick_frames(sr, wanted)
    s = sr.summary
    root = out.parent

    def _rel(v):
        if isinstance(v, list):
            return [_rel(x) for x in v]
        return str(Path(v).relative_to(root)) if Path(v).is_relative_to(root) else v

    rel = {k: _rel(v) for k, v in files.items()}
    entry = {
        "name": name,
        "scene_file": str(path),
        "title": desc["title"],
        "paper": desc["paper"],
        "scene": desc["scene"],
        "scale": scale,
        "grid_shape": s["grid"]["shape"],
        "cells_per_wavelength": s["grid"]["cells_per_wavelength"],
        "n_steps": s["run"]["n_steps"],
        "shown_steps": [st for _, st in frames],
        "simulate_wall_time_s": s["run"]["wall_time_s"],
        "run_wall_time_s": t_sim,
        "render_wall_time_s": time.perf_counter() - t0,
        "stability_finite": s["stability"]["finite"],
        "peak_pa": s["stability"]["peak_pa"],
        "files": rel,
    }
    del sr
    return entry


def render_gallery(
    out_dir, *, scale: float = 1.0, names=None, progress: bool = True, scenes_dir: str | Path | None = None
) -> list[dict]:
    """Render the paper's gallery (see the module docstring); returns one entry per scene."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = _select(scene_files(scenes_dir), names)
    entries = []
    t_all = time.perf_counter()
    for i, f in enumerate(files):
        if progress:
            print(f"[{i + 1}/{len(files)}] {f.stem} (scale {scale:g})", flush=True)
        e = render_scene(f, out / f.stem, scale=scale, progress=progress)
        entries.append(e)
        if progress:
            print(
                f"    {e['n_steps']} steps on {e['grid_shape'][0]} x {e['grid_shape'][1]} cells: "
                f"{e['render_wall_time_s']:.1f} s",
                flush=True,
            )
    comparisons = {}
    for key, spec in COMPARISONS.items():
        p = write_comparison(out, key, spec, scale)
        if p is not None:
            comparisons[key] = str(p.relative_to(out))
    meta = {
        "scale": scale,
        "scenes_dir": str(files[0].parent) if files else None,
        "total_wall_time_s": time.perf_counter() - t_all,
        "comparisons": comparisons,
        "scenes": entries,
    }
    from .. import __version__

    meta["difflattice_version"] = __version__
    (out / "gallery.json").write_text(json.dumps(meta, indent=2))
    (out / "index.md").write_text(index_markdown(entries, comparisons, scale))
    return entries


def index_markdown(entries: list[dict], comparisons: dict, scale: float) -> str:
    cpw = 20 * scale
    lines = [
        "# Gallery: the figures of McKerrow, Zhu & New (2001)",
        "",
        f"Rendered by `difflattice gallery --scale {scale:g}` from `data/scenes/fig*.toml` "
        f"({cpw:g} cells per wavelength{'' if scale == 1 else '; the paper used 20, so this is a coarser look'}). "
        "Each image shows the pressure field (white +, black -, every few cells rendered as in the paper), "
        "obstacle outlines in orange, transducer cells in red, probes as cyan crosses.",
        "",
    ]
    by_fig = {}
    for k, p in comparisons.items():
        by_fig[k] = p
    for e in entries:
        lines += [f"## {e['name']}", "", f"**{e['title']}**", ""]
        if e["paper"]:
            lines += [e["paper"], ""]
        if e["scene"]:
            lines += [f"*Scene:* {e['scene'][len('Here: ') :]}", ""]
        f = e["files"]
        lines += [f"![{e['name']}]({f['figure']})", ""]
        extra = [
            f"[{k}]({v})"
            for k, v in f.items()
            if k in ("field", "peak_level", "lobe", "probes", "wavefront", "animation", "summary")
        ]
        lines += [
            f"{e['grid_shape'][0]} x {e['grid_shape'][1]} cells, {e['n_steps']} steps "
            f"(shown: {', '.join(str(s) for s in e['shown_steps'])}), "
            f"rendered in {e['render_wall_time_s']:.1f} s (simulation {e['simulate_wall_time_s']:.1f} s). "
            f"Files: {', '.join(extra)}.",
            "",
        ]
        if "wavefront" in f:
            lines += [f"![wavefront]({f['wavefront']})", ""]
        key = e["name"][:5]
        if key in by_fig and COMPARISONS[key]["scenes"][-1] == e["name"]:
            lines += [f"![{COMPARISONS[key]['title']}]({by_fig[key]})", ""]
    return "\n".join(lines)


def export_images(out_dir: str | Path, dest: str | Path, *, colors: int = 128) -> list[Path]:
    """Copy each scene's figure.png (as <name>.png), wavefront.png, peak_level.png (as
    <name>_peak.png) and the comparison plots from a rendered gallery into `dest` as palette PNGs
    (`colors` colours: small files for the docs)."""
    from PIL import Image

    out, dest = Path(out_dir), Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    written = []
    srcs = [(p, f"{p.parent.name}.png") for p in sorted(out.glob("*/figure.png"))]
    srcs += [(p, f"{p.parent.name}_wavefront.png") for p in sorted(out.glob("*/wavefront.png"))]
    srcs += [(p, f"{p.parent.name}_peak.png") for p in sorted(out.glob("*/peak_level.png"))]
    srcs += [(p, p.name) for p in sorted(out.glob("compare_*.png"))]
    for src, name in srcs:
        im = Image.open(src).convert("RGB").quantize(colors=colors, method=Image.Quantize.MEDIANCUT)
        im.save(dest / name, optimize=True)
        written.append(dest / name)
    return written
