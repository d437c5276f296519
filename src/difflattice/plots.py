"""Pictures: pressure fields like the paper's figures, lobe patterns, wavefronts, time series,
aperture profiles and animations. Matplotlib is imported here only (the core never imports it);
every function takes numpy-convertible arrays and returns the matplotlib Figure or writes a file.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use("Agg") if matplotlib.get_backend().lower() not in ("agg", "pdf", "svg") else None
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .scene.model import MIN_PIXELS_PER_WAVELENGTH, PAPER_RENDER_EVERY, render_stride  # noqa: E402,F401


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
):
    """Grayscale pressure image with a symmetric scale (white = +, black = -), rendering every
    `every`-th cell (the paper used every third; `render_stride` picks it from the resolution),
    obstacle outlines, transducer cells, axes in mm and a time stamp in steps and microseconds.
    `clip` sets the scale as a fraction of max |p|. `dx_m` is the simulation's cell (obstacles and
    source cells are in its cells); `size_m` is the window's size, default `p.shape * dx_m` (give
    it when `p` was already thinned, e.g. a snapshot kept at every n-th cell, with `every=1`)."""
    p = np.asarray(p)
    if isinstance(every, bool) or int(every) != every or every < 1:
        raise ValueError(f"every = {every!r}: render every n-th cell, n a whole number >= 1")
    sub = p[::every, ::every]
    vmax = float(np.abs(p).max()) * clip or 1.0
    fig = None
    w_m, h_m = size_m if size_m is not None else (p.shape[0] * dx_m, p.shape[1] * dx_m)
    if ax is None:
        fig, ax = plt.subplots(figsize=(7, 7 * h_m / w_m + 0.6))
    ext_mm = [0, w_m * 1e3, 0, h_m * 1e3]
    ax.imshow(sub.T, origin="lower", cmap="gray", vmin=-vmax, vmax=vmax, extent=ext_mm, interpolation="nearest")
    if obstacles is not None:
        occ = np.asarray(obstacles)
        if occ.max() > 0:
            x = (np.arange(occ.shape[0]) + 0.0) * dx_m * 1e3
            y = (np.arange(occ.shape[1]) + 0.0) * dx_m * 1e3
            ax.contour(x, y, occ.T, levels=[0.5], colors="tab:orange", linewidths=1.0)
    for cells in sources:
        c = np.asarray(cells)
        ax.plot(c[:, 0] * dx_m * 1e3, c[:, 1] * dx_m * 1e3, color="tab:red", lw=2)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    stamp = []
    if step is not None:
        stamp.append(f"step {step}")
        if dt_s is not None:
            stamp.append(f"{step * dt_s * 1e6:.1f} µs")
    ax.set_title(title or "  ".join(stamp))
    if title and stamp:
        ax.text(0.01, 0.99, "  ".join(stamp), transform=ax.transAxes, va="top", color="tab:blue", fontsize=8)
    return fig if fig is not None else ax.figure


def level_image(p_max, dx_m: float, *, floor_db: float = -60.0, sources=(), title="peak level (dB re max)"):
    """Peak |p| map in dB (for beam patterns)."""
    a = np.asarray(p_max)
    db = 20 * np.log10(np.maximum(a / max(float(a.max()), 1e-30), 10 ** (floor_db / 20)))
    fig, ax = plt.subplots(figsize=(7, 7 * a.shape[1] / a.shape[0] + 0.6))
    im = ax.imshow(db.T, origin="lower", cmap="magma", vmin=floor_db, vmax=0,
                   extent=[0, a.shape[0] * dx_m * 1e3, 0, a.shape[1] * dx_m * 1e3])
    for cells in sources:
        c = np.asarray(cells)
        ax.plot(c[:, 0] * dx_m * 1e3, c[:, 1] * dx_m * 1e3, color="cyan", lw=2)
    fig.colorbar(im, ax=ax, label="dB")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(title)
    return fig


def lobe_plots(angles_deg, curves: dict, *, floor_db: float = -50.0, title: str = "lobe pattern"):
    """Polar and cartesian lobe patterns in dB; `curves` maps a label to levels in dB (or
    (levels, style) pairs). Measured data can be given as (levels, "o")."""
    fig = plt.figure(figsize=(12, 5))
    axp = fig.add_subplot(1, 2, 1, projection="polar")
    axc = fig.add_subplot(1, 2, 2)
    a = np.asarray(angles_deg)
    for label, v in curves.items():
        lv, style = (v if isinstance(v, tuple) else (v, "-"))
        lv = np.maximum(np.asarray(lv), floor_db)
        kw = {"ms": 3} if style not in ("-", "--", ":") else {}
        axp.plot(np.radians(a), lv - floor_db, style, label=label, **kw)
        axc.plot(a, lv, style, label=label, **kw)
    axp.set_thetamin(float(a.min()))
    axp.set_thetamax(float(a.max()))
    axp.set_rticks([10, 20, 30, 40, 50][: int(-floor_db // 10)])
    axp.set_yticklabels([f"{floor_db + r:.0f}" for r in axp.get_yticks()])
    axp.set_title(title + " (polar, dB)")
    axc.set_xlabel("angle (deg)")
    axc.set_ylabel("level (dB)")
    axc.set_ylim(floor_db, 3)
    axc.grid(True, alpha=0.3)
    axc.legend()
    fig.tight_layout()
    return fig


def wavefront_plot(x_m, curves: dict, *, ylabel="arrival (µs)", title="near-field wavefront"):
    fig, ax = plt.subplots(figsize=(7, 4))
    for label, v in curves.items():
        y, style = (v if isinstance(v, tuple) else (v, "-"))
        ax.plot(np.asarray(x_m) * 1e3, y, style, label=label, ms=4)
    ax.set_xlabel("lateral position x (mm)")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend()
    return fig


def aperture_plot(y_m, weights, lags_s, *, labels=("fitted",), title="aperture"):
    """Weights and lags across the aperture; `weights`/`lags_s` may be lists of arrays."""
    ws = weights if isinstance(weights, (list, tuple)) else [weights]
    ls = lags_s if isinstance(lags_s, (list, tuple)) else [lags_s]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4))
    for w, lag, lab in zip(ws, ls, labels):
        a1.plot(np.asarray(y_m) * 1e3, np.asarray(w), label=lab)
        a2.plot(np.asarray(y_m) * 1e3, np.asarray(lag) * 1e6, label=lab)
    a1.set_xlabel("position across the face (mm)")
    a1.set_ylabel("weight")
    a2.set_xlabel("position across the face (mm)")
    a2.set_ylabel("lag (µs)")
    for a in (a1, a2):
        a.grid(True, alpha=0.3)
        a.legend()
    fig.suptitle(title)
    fig.tight_layout()
    return fig


MAX_LEGEND_ENTRIES = 8
"""Probe time series: a legend up to this many probes, a colour bar (probe index) beyond."""


def time_series_plot(t_s, series, labels):
    """Pressure against time (µs), one curve per column of `series`. Up to `MAX_LEGEND_ENTRIES`
    curves get a legend entry each; more are coloured by their index with a colour bar."""
    series = np.asarray(series).reshape(len(np.asarray(t_s)), -1)
    n = series.shape[1]
    fig, ax = plt.subplots(figsize=(8, 4))
    if n <= MAX_LEGEND_ENTRIES:
        for s, lab in zip(series.T, labels):
            ax.plot(np.asarray(t_s) * 1e6, s, label=lab)
        if n:
            ax.legend()
    else:
        cmap = plt.get_cmap("viridis")
        norm = matplotlib.colors.Normalize(vmin=0, vmax=n - 1)
        for i, s in enumerate(series.T):
            ax.plot(np.asarray(t_s) * 1e6, s, color=cmap(norm(i)), lw=0.8)
        sm = matplotlib.cm.ScalarMappable(norm=norm, cmap=cmap)
        fig.colorbar(sm, ax=ax, label=f"probe index ({n} probes)")
    ax.set_xlabel("time (µs)")
    ax.set_ylabel("pressure (Pa)")
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
    fig, ax = plt.subplots(figsize=(6, 6 * aspect + 0.6))
    vmax = float(np.abs(frames).max()) * 0.5 or 1.0

    def draw(i):
        ax.clear()
        field_image(frames[i] / vmax * 2.0, dx_m, every=every, step=int(steps[i]), dt_s=dt_s, ax=ax, clip=1.0, **kw)
        return []

    if path.suffix == ".mp4" and animation.writers.is_available("ffmpeg"):
        writer = animation.FFMpegWriter(fps=fps)
    else:
        path = path.with_suffix(".gif")
        writer = animation.PillowWriter(fps=fps)
    anim = animation.FuncAnimation(fig, draw, frames=len(frames), blit=False)
    anim.save(str(path), writer=writer)
    plt.close(fig)
    return path


def save(fig, path: str | Path, dpi: int = 110) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return path
