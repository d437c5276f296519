"""Pictures: pressure fields like the paper's figures, lobe patterns, wavefronts, time series,
aperture profiles and animations. Matplotlib is imported here only (the core never imports it);
every function takes numpy-convertible arrays and returns a `matplotlib.figure.Figure` or writes
a file.

Figures are built with `Figure` directly, not pyplot: no backend is chosen or forced at import,
nothing is registered in pyplot's global figure list (so library calls are re-entrant and need
no closing), and `save` writes through the figure's own canvas. In a notebook a returned Figure
displays as usual; `plt.figure()`-made figures passed to `save` are closed there.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, cast

import matplotlib
import numpy as np
from matplotlib.figure import Figure
from matplotlib.projections.polar import PolarAxes

from .scene.model import MIN_PIXELS_PER_WAVELENGTH, PAPER_RENDER_EVERY, render_stride  # noqa: F401


def field_image(
    p,
    dx_m: float,
    *,
    every: int = 3,
    step: int | None = None,
    dt_s: float | None = None,
    obstacles=None,
    sources: Sequence[np.ndarray] = (),
    clip: float = 0.5,
    title: str | None = None,
    ax=None,
    size_m: tuple[float, float] | None = None,
    colorbar: bool | None = None,
    units: str = "Pa",
    axis_labels: tuple[str, str] = ("x (mm)", "y (mm)"),
    origin_m: tuple[float, float] = (0.0, 0.0),
):
    """Grayscale pressure image with a symmetric scale (white = +, black = -), rendering every
    `every`-th cell (the paper used every third; `render_stride` picks it from the resolution),
    obstacle outlines, transducer cells, axes in mm, a time stamp in steps and microseconds and a
    colour bar of the pressure (`units`; values beyond the scale are saturated). `clip` sets the
    scale as a fraction of max |p|. `dx_m` is the simulation's cell (obstacles and source cells
    are in its cells); `size_m` is the window's size, default `p.shape * dx_m` (give it when `p`
    was already thinned, e.g. a snapshot kept at every n-th cell, with `every=1`). `colorbar`:
    default on for a new figure, off when drawing into a given `ax` (panels, animations).
    `axis_labels`: the lattice kind's (`LatticeKind.axis_labels`, e.g. z/r on an rz grid);
    `origin_m`: coordinates of the image's low corner (e.g. (0, -R) for a mirrored rz section)."""
    p = np.asarray(p)
    if isinstance(every, bool) or int(every) != every or every < 1:
        raise ValueError(f"every = {every!r}: render every n-th cell, n a whole number >= 1")
    sub = p[::every, ::every]
    vmax = float(np.abs(p).max()) * clip or 1.0
    fig = None
    w_m, h_m = size_m if size_m is not None else (p.shape[0] * dx_m, p.shape[1] * dx_m)
    if ax is None:
        fig = Figure(figsize=(7.8, 7 * h_m / w_m + 0.6))
        ax = fig.add_subplot()
    if colorbar is None:
        colorbar = fig is not None
    x0, y0 = (o * 1e3 for o in origin_m)
    ext_mm = [x0, x0 + w_m * 1e3, y0, y0 + h_m * 1e3]
    im = ax.imshow(sub.T, origin="lower", cmap="gray", vmin=-vmax, vmax=vmax, extent=ext_mm, interpolation="nearest")
    if colorbar:
        ax.figure.colorbar(im, ax=ax, shrink=0.8, extend="both", label=f"pressure ({units})")
    if obstacles is not None:
        occ = np.asarray(obstacles)
        if occ.max() > 0:
            x = x0 + np.arange(occ.shape[0]) * dx_m * 1e3
            y = y0 + np.arange(occ.shape[1]) * dx_m * 1e3
            ax.contour(x, y, occ.T, levels=[0.5], colors="tab:orange", linewidths=1.0)
    for cells in sources:
        c = np.asarray(cells)
        ax.plot(x0 + c[:, 0] * dx_m * 1e3, y0 + c[:, 1] * dx_m * 1e3, color="tab:red", lw=2)
    ax.set_xlabel(axis_labels[0])
    ax.set_ylabel(axis_labels[1])
    stamp = []
    if step is not None:
        stamp.append(f"step {step}")
        if dt_s is not None:
            stamp.append(f"{step * dt_s * 1e6:.1f} µs")
    ax.set_title(title or "  ".join(stamp))
    if title and stamp:
        ax.text(0.01, 0.99, "  ".join(stamp), transform=ax.transAxes, va="top", color="tab:blue", fontsize=8)
    return fig if fig is not None else ax.figure


def _db_image(a, dx_m: float, floor_db: float, origin_m: tuple[float, float] = (0.0, 0.0)):
    """A 2-D magnitude map in dB re its peak (floored at `floor_db`), axes in mm, with a colour bar."""
    db = 20 * np.log10(np.maximum(a / max(float(a.max()), 1e-30), 10 ** (floor_db / 20)))
    fig = Figure(figsize=(7, 7 * a.shape[1] / a.shape[0] + 0.6))
    ax = fig.add_subplot()
    x0, y0 = (o * 1e3 for o in origin_m)
    extent = (x0, x0 + a.shape[0] * dx_m * 1e3, y0, y0 + a.shape[1] * dx_m * 1e3)
    im = ax.imshow(db.T, origin="lower", cmap="magma", vmin=floor_db, vmax=0, extent=extent)
    fig.colorbar(im, ax=ax, label="dB")
    return fig, ax


def level_image(
    p_max,
    dx_m: float,
    *,
    floor_db: float = -60.0,
    sources=(),
    title="peak level (dB re max)",
    axis_labels: tuple[str, str] = ("x (mm)", "y (mm)"),
    origin_m: tuple[float, float] = (0.0, 0.0),
):
    """Peak |p| map in dB (for beam patterns); `axis_labels` and `origin_m` as in `field_image`."""
    fig, ax = _db_image(np.asarray(p_max), dx_m, floor_db, origin_m)
    x0, y0 = (o * 1e3 for o in origin_m)
    for cells in sources:
        c = np.asarray(cells)
        ax.plot(x0 + c[:, 0] * dx_m * 1e3, y0 + c[:, 1] * dx_m * 1e3, color="cyan", lw=2)
    ax.set_xlabel(axis_labels[0])
    ax.set_ylabel(axis_labels[1])
    ax.set_title(title)
    return fig


def lobe_plots(angles_deg, curves: dict, *, floor_db: float = -50.0, title: str = "lobe pattern"):
    """Polar and cartesian lobe patterns in dB; `curves` maps a label to levels in dB (or
    (levels, style) pairs). Measured data can be given as (levels, "o"). The polar plot's rings
    are labelled in dB re the peak (0 dB outermost), both panels carry the legend."""
    fig = Figure(figsize=(12, 5.2))
    axp = cast(PolarAxes, fig.add_subplot(1, 2, 1, projection="polar"))
    axc = fig.add_subplot(1, 2, 2)
    a = np.asarray(angles_deg)
    for label, v in curves.items():
        lv, style = v if isinstance(v, tuple) else (v, "-")
        lv = np.maximum(np.asarray(lv), floor_db)
        kw: dict[str, Any] = {"ms": 3} if style not in ("-", "--", ":") else {}
        axp.plot(np.radians(a), lv - floor_db, style, label=label, **kw)
        axc.plot(a, lv, style, label=label, **kw)
    axp.set_thetamin(float(a.min()))
    axp.set_thetamax(float(a.max()))
    axp.set_theta_zero_location("N")
    axp.set_theta_direction(-1)
    rings = np.arange(0.0, -floor_db + 1e-9, 10.0)
    axp.set_rlim(0, -floor_db + 2)
    axp.set_rticks(rings[1:])
    axp.set_yticklabels([])
    label_at = np.radians(min(float(a.max()), 180.0) * 0.85)  # ring labels along one ray, where side lobes are low
    for r in rings[1:]:
        axp.text(
            label_at,
            r,
            f"{floor_db + r:.0f} dB",
            fontsize=7,
            ha="center",
            va="center",
            bbox={"boxstyle": "round,pad=0.1", "fc": "white", "ec": "none", "alpha": 0.8},
        )
    axp.set_xlabel("angle from the axis (deg); rings: level re peak")
    axp.set_title(title + " (polar)", pad=12)
    axp.legend(loc="upper left", bbox_to_anchor=(-0.12, 1.0), fontsize=7)
    axc.set_xlabel("angle (deg)")
    axc.set_ylabel("level (dB re peak)")
    axc.set_ylim(floor_db, 3)
    axc.grid(True, alpha=0.3)
    axc.legend(fontsize=8)
    axc.set_title(title)
    fig.tight_layout()
    return fig


def wavefront_plot(x_m, curves: dict, *, ylabel="arrival (µs)", title="near-field wavefront"):
    """Curves against lateral position (mm); `curves` maps a label to values or (values, style)."""
    fig = Figure(figsize=(7, 4))
    ax = fig.add_subplot()
    for label, v in curves.items():
        y, style = v if isinstance(v, tuple) else (v, "-")
        ax.plot(np.asarray(x_m) * 1e3, y, style, label=label, ms=4)
    ax.set_xlabel("lateral position x (mm)")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend()
    return fig


def aperture_plot(
    y_m,
    weights,
    lags_s,
    *,
    labels=("fitted",),
    title="aperture",
    weight_err=None,
    lag_err_s=None,
    truth: dict | None = None,
    weight_label: str = "weight",
    band_label: str = "± total uncertainty",
):
    """Weights and lags across the aperture; `weights`/`lags_s` may be lists of arrays (one per
    label). `weight_err`/`lag_err_s` (same length as the first curve, NaN where undetermined)
    draw a shaded band around the first curve; `truth` ({"y_m", "weights", "lags_s"}) is
    overlaid as a dashed black line when known (e.g. emulated data)."""
    ws = weights if isinstance(weights, (list, tuple)) else [weights]
    ls = lags_s if isinstance(lags_s, (list, tuple)) else [lags_s]
    fig = Figure(figsize=(11, 4))
    a1, a2 = fig.subplots(1, 2)
    y_mm = np.asarray(y_m) * 1e3
    for i, (w, lag, lab) in enumerate(zip(ws, ls, labels)):
        a1.plot(y_mm, np.asarray(w), label=lab)
        a2.plot(y_mm, np.asarray(lag) * 1e6, label=lab)
        if i == 0:
            for ax, v, e, scale in ((a1, w, weight_err, 1.0), (a2, lag, lag_err_s, 1e6)):
                if e is not None:
                    v, e = np.asarray(v, float) * scale, np.asarray(e, float) * scale
                    ok = np.isfinite(e)
                    ax.fill_between(
                        y_mm,
                        np.where(ok, v - e, np.nan),
                        np.where(ok, v + e, np.nan),
                        alpha=0.25,
                        color="tab:blue",
                        label=band_label,
                    )
    if truth is not None:
        ty = np.asarray(truth["y_m"]) * 1e3
        if truth.get("weights") is not None:
            a1.plot(ty, np.asarray(truth["weights"]), "k--", lw=1.2, label="truth")
        if truth.get("lags_s") is not None:
            a2.plot(ty, np.asarray(truth["lags_s"]) * 1e6, "k--", lw=1.2, label="truth")
    a1.set_xlabel("position across the face (mm)")
    a1.set_ylabel(weight_label)
    a2.set_xlabel("position across the face (mm)")
    a2.set_ylabel("lag (µs)")
    for a in (a1, a2):
        a.grid(True, alpha=0.3)
        a.legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    return fig


MAX_LEGEND_ENTRIES = 8
"""Probe time series: a legend up to this many probes, a colour bar (probe index) beyond."""


def time_series_plot(t_s, series, labels, *, ylabel: str = "pressure (Pa)"):
    """Pressure against time (µs), one curve per column of `series`. Up to `MAX_LEGEND_ENTRIES`
    curves get a legend entry each; more are coloured by their index with a colour bar. `ylabel`
    names the quantity and its unit (e.g. a transducer's weighted sum is not a pressure in Pa)."""
    series = np.asarray(series).reshape(len(np.asarray(t_s)), -1)
    n = series.shape[1]
    fig = Figure(figsize=(8, 4))
    ax = fig.add_subplot()
    if n <= MAX_LEGEND_ENTRIES:
        for s, lab in zip(series.T, labels):
            ax.plot(np.asarray(t_s) * 1e6, s, label=lab)
        if n:
            ax.legend()
    else:
        cmap = matplotlib.colormaps["viridis"]
        norm = matplotlib.colors.Normalize(vmin=0, vmax=n - 1)
        for i, s in enumerate(series.T):
            ax.plot(np.asarray(t_s) * 1e6, s, color=cmap(norm(i)), lw=0.8)
        sm = matplotlib.cm.ScalarMappable(norm=norm, cmap=cmap)
        fig.colorbar(sm, ax=ax, label=f"probe index ({n} probes)")
    ax.set_xlabel("time (µs)")
    ax.set_ylabel(ylabel)
    ax.grid(True, alpha=0.3)
    return fig


def animate(frames, steps, dx_m: float, dt_s: float, path: str | Path, *, every: int = 3, fps: int = 10, **kw):
    """Write an animation (GIF, or MP4 where ffmpeg is installed) from snapshots, one frame at a
    time (no full-resolution history is built). Returns the path written."""
    from matplotlib import animation

    path = Path(path)
    frames = np.asarray(frames)
    size_m = kw.get("size_m")
    aspect = size_m[1] / size_m[0] if size_m is not None else frames.shape[2] / frames.shape[1]
    fig = Figure(figsize=(6, 6 * aspect + 0.6))
    ax = fig.add_subplot()
    vmax = float(np.abs(frames).max()) * 0.5 or 1.0

    def draw(i):
        ax.clear()
        field_image(frames[i] / vmax * 2.0, dx_m, every=every, step=int(steps[i]), dt_s=dt_s, ax=ax, clip=1.0, **kw)
        return []

    if path.suffix == ".mp4" and animation.writers.is_available("ffmpeg"):
        writer: animation.AbstractMovieWriter = animation.FFMpegWriter(fps=fps)
    else:
        path = path.with_suffix(".gif")
        writer = animation.PillowWriter(fps=fps)
    anim = animation.FuncAnimation(fig, draw, frames=len(frames), blit=False)
    anim.save(str(path), writer=writer)
    return path


def save(fig, path: str | Path, dpi: int = 110) -> Path:
    """Write `fig` (any matplotlib Figure) to `path`; a pyplot-managed figure is closed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi, bbox_inches="tight")
    plt = sys.modules.get("matplotlib.pyplot")
    if plt is not None and plt.fignum_exists(getattr(fig, "number", -1)):
        plt.close(fig)
    return path


# ------------------------------------------------------------------------------------------
# 3-D fields (issue 16): slices through the transducer axis, projections, echo against angle


def slices_3d(
    slices: dict,
    dx_m: float,
    *,
    floor_db: float | None = None,
    clip: float = 0.5,
    marks: dict | None = None,
    outlines: dict | None = None,
    title: str = "3-D field, orthogonal slices",
):
    """Orthogonal slices of a 3-D field side by side. `slices` maps a label (e.g. "x-y at z = 12 mm")
    to ((horizontal axis name, vertical axis name), 2-D array indexed [horizontal, vertical]).
    With `floor_db` each panel is the level in dB re the largest |p| of all panels (for p_max or
    p_rms maps); otherwise a symmetric gray scale clipped at `clip` x max |p| (a snapshot).
    `marks` maps a label to (n, 2) cell positions (e.g. the transducer cells) drawn in cyan;
    `outlines` maps a label to a 2-D occupancy on the same plane (an obstacle), outlined at 0.5."""
    items = list(slices.items())
    if not items:
        raise ValueError("slices is empty: give at least one labelled 2-D array")
    peak = max(float(np.abs(np.asarray(a)).max()) for _, (_, a) in items) or 1.0
    fig = Figure(figsize=(5.2 * len(items), 4.8))
    axes = fig.subplots(1, len(items), squeeze=False)
    for ax, (label, (names, arr)) in zip(axes[0], items):
        a = np.asarray(arr, dtype=float)
        ext = [0, a.shape[0] * dx_m * 1e3, 0, a.shape[1] * dx_m * 1e3]
        if floor_db is not None:
            db = 20 * np.log10(np.maximum(np.abs(a) / peak, 10 ** (floor_db / 20)))
            im = ax.imshow(db.T, origin="lower", cmap="magma", vmin=floor_db, vmax=0, extent=ext)
        else:
            im = ax.imshow(a.T, origin="lower", cmap="gray", vmin=-clip * peak, vmax=clip * peak, extent=ext)
        occ = (outlines or {}).get(label)
        if occ is not None and np.asarray(occ).max() > 0.5:
            o = np.asarray(occ, dtype=float)
            ax.contour(
                np.arange(o.shape[0]) * dx_m * 1e3,
                np.arange(o.shape[1]) * dx_m * 1e3,
                o.T,
                levels=[0.5],
                colors="tab:orange",
                linewidths=1.0,
            )
        for c in (marks or {}).get(label, ()):
            c = np.asarray(c, dtype=float).reshape(-1, 2)
            ax.plot(c[:, 0] * dx_m * 1e3, c[:, 1] * dx_m * 1e3, ".", color="cyan", ms=2)
        ax.set_xlabel(f"{names[0]} (mm)")
        ax.set_ylabel(f"{names[1]} (mm)")
        ax.set_title(label, fontsize=10)
    fig.colorbar(im, ax=list(axes[0]), label="dB" if floor_db is not None else "Pa", shrink=0.8)
    fig.suptitle(title)
    return fig


def max_intensity_projection(volume, dx_m: float, *, axis: int = 2, floor_db: float = -40.0, title: str | None = None):
    """Maximum of |volume| along `axis` (0 = x, 1 = y, 2 = z) in dB re its peak: a 3-D beam or
    echo field seen through the volume (give p_max or p_rms of a 3-D run)."""
    v = np.abs(np.asarray(volume, dtype=float))
    if v.ndim != 3:
        raise ValueError(f"max_intensity_projection needs a 3-D array, got shape {v.shape}")
    m = v.max(axis=axis)
    names = [n for i, n in enumerate("xyz") if i != axis]
    fig, ax = _db_image(m, dx_m, floor_db)
    ax.set_xlabel(f"{names[0]} (mm)")
    ax.set_ylabel(f"{names[1]} (mm)")
    ax.set_title(title or f"maximum-intensity projection along {'xyz'[axis]} (dB re max)")
    return fig


def echo_angle_plot(angles_deg, curves: dict, *, title: str = "echo amplitude against incidence angle"):
    """Echo amplitude (dB) against angle; `curves` maps a label to levels in dB, or to (levels,
    style) pairs (e.g. the 3-D lattice as "o-" and the image-source reference as "--")."""
    fig = Figure(figsize=(7, 4.5))
    ax = fig.add_subplot()
    a = np.asarray(angles_deg, dtype=float)
    for label, v in curves.items():
        lv, style = v if isinstance(v, tuple) else (v, "o-")
        ax.plot(a, np.asarray(lv, dtype=float), style, label=label, ms=4)
    ax.set_xlabel("incidence angle (deg)")
    ax.set_ylabel("echo level (dB)")
    ax.grid(True, alpha=0.3)
    ax.legend()
    ax.set_title(title)
    fig.tight_layout()
    return fig


def convergence_plot(trace):
    """A fit's convergence: cost against solver iteration, one colour per stage, stage
    boundaries marked and named; and cost against solve time with compilation excluded (it is
    stated in the title). `trace`: arrays `iteration`, `stage`, `cost`, `accepted`, `solve_s`,
    `stages` (dicts: stage, name, first_iteration, result_code) and `compile_s` (as
    `fit.solve.FitTrace`). The stages' costs are on different scales (stages 1-2 floor the
    sigmas), so each is drawn on its own and the boundaries are where the cost jumps."""
    fig = Figure(figsize=(11, 4.2))
    a1, a2 = fig.subplots(1, 2)
    it = trace.iteration
    for s in trace.stages:
        m = trace.stage == s["stage"]
        if not m.any():
            continue
        best = np.minimum.accumulate(trace.cost[m])
        (line,) = a1.semilogy(it[m], best, "-", label=f"stage {s['stage']}: {s['name']}")
        rej = m & ~trace.accepted
        a1.semilogy(it[rej], trace.cost[rej], "x", ms=3, color=line.get_color(), alpha=0.5)
        a1.axvline(s["first_iteration"] - 0.5, color="0.6", lw=0.8, ls=":")
        a1.text(s["first_iteration"], best[0], f" {s['stage']}", fontsize=8, va="bottom", color=line.get_color())
        a2.semilogy(trace.solve_s[m], best, "-", color=line.get_color())
    a1.set_xlabel("solver iteration (x: trial step rejected; dotted: stage boundaries)")
    a1.set_ylabel("cost (half sum of squared residuals)")
    a1.legend(fontsize=7, loc="lower left")
    a1.grid(True, alpha=0.3, which="both")
    a2.set_xlabel("solve time (s), compilation excluded")
    a2.set_ylabel("cost")
    a2.grid(True, alpha=0.3, which="both")
    n_conv = [s for s in trace.stages if s["stage"] == max(t["stage"] for t in trace.stages)]
    verdict = n_conv[0]["result_code"] if n_conv else ""
    fig.suptitle(
        f"convergence: {len(it)} iterations, final stage {verdict}; compilation {trace.compile_s:.1f} s (not shown)",
        fontsize=10,
    )
    fig.tight_layout()
    return fig


def _warm_up() -> None:
    """Draw and encode one small figure with what the report's figures use (a log axis with its
    mathtext tick labels, a polar axis, an image, a legend, the tight layouts): a process's first
    such figure pays for the fonts, the text layout and the renderers (~0.3-0.4 s for a fit's
    report), and the worker is idle while the fit runs, so it pays for them then."""
    import io

    fig = Figure(figsize=(4, 2))
    a1 = fig.add_subplot(1, 3, 1)
    a1.semilogy([1, 2, 3], [1.0, 10.0, 1000.0], "-", label="a")
    a1.grid(True, alpha=0.3, which="both")
    a1.legend(fontsize=7)
    a1.set_xlabel("x")
    a2 = fig.add_subplot(1, 3, 2, projection="polar")
    a2.plot(np.linspace(0, np.pi, 5), np.ones(5))
    a3 = fig.add_subplot(1, 3, 3)
    a3.imshow(np.zeros((4, 4)), cmap="RdBu_r")
    fig.suptitle("warm-up", fontsize=10)
    fig.tight_layout()
    fig.savefig(io.BytesIO(), format="png", dpi=110, bbox_inches="tight")


def _render_jobs(stream) -> dict[str, str]:
    """The report's figure worker (`fit.report.FigureWriter`): render the pickled jobs
    (name, function name in this module, path, args, kwargs) the calling process streams to
    `stream`, as they come (after `_warm_up`)."""
    import pickle

    _warm_up()
    done: dict[str, str] = {}
    while True:
        try:
            name, fn, out, args, kwargs = pickle.load(stream)  # noqa: S301 (from the parent process)
        except EOFError:
            return done
        done[name] = str(save(globals()[fn](*args, **kwargs), out))


if __name__ == "__main__":
    import json

    if sys.argv[1:] != ["--render-jobs", "-"]:
        raise SystemExit("usage: python -m difflattice.plots --render-jobs -  (pickled jobs on stdin)")
    print(json.dumps(_render_jobs(sys.stdin.buffer)))
