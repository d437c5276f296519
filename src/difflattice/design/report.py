"""Design reports: a directory with JSON, Markdown and PNGs for a start and an optimised design.

Pictures: the two shapes (wall outlines), the objective and the goal's measures against wall
time, beam patterns in dB (polar and cartesian, with the bare transducer), field snapshots and
peak-level maps of both designs. Matplotlib is imported here only.
"""

from __future__ import annotations

import json
import platform
import time
from pathlib import Path

import numpy as np

from ..air import SPEED_OF_SOUND_20C_M_S
from .problem import DesignProblem


def _levels_db(p, ref):
    return 20 * np.log10(np.maximum(np.abs(np.asarray(p)) / ref, 1e-6))


def resolution_note(problem: DesignProblem) -> str:
    g = problem.grid
    return (
        f"{g.cells_per_wavelength * SPEED_OF_SOUND_20C_M_S / g.c_max_m_s:.1f} cells per wavelength in air at "
        f"{g.frequency_hz / 1e3:.0f} kHz (cell {g.dx_m * 1e3:.3f} mm), grid {g.shape[0]} x {g.shape[1]}, "
        f"{problem.n_steps} steps, {g.dtype}; beam at {problem.range_m} m by the Kirchhoff-Helmholtz transform"
    )


def shape_plot(problem: DesignProblem, designs: dict, ax=None):
    """Wall outlines (occupancy 0.5 contours) of several designs, mm."""
    import matplotlib.pyplot as plt

    fig = None
    if ax is None:
        fig, ax = plt.subplots(figsize=(7, 5))
    g = problem.grid
    x, y = (np.arange(n) * g.dx_m * 1e3 for n in g.shape)
    colors = ["tab:gray", "tab:red", "tab:blue", "tab:green"]
    for (label, params), c in zip(designs.items(), colors):
        occ = np.asarray(problem.occupancy(params))
        ax.contour(x, y, occ.T, levels=[0.5], colors=c, linewidths=1.5)
        ax.plot([], [], color=c, label=label)  # contour sets have no legend handle
    cells = problem.source().cells_array
    ax.plot(cells[:, 0] * g.dx_m * 1e3, cells[:, 1] * g.dx_m * 1e3, color="k", lw=3, label="transducer")
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.legend(fontsize=8)
    ax.set_title("wall outlines")
    return fig if fig is not None else ax.figure


def history_plot(result):
    import matplotlib.pyplot as plt

    h = result.history
    t = [r["wall_s"] for r in h]
    fig, axs = plt.subplots(1, 3, figsize=(13, 3.6))
    axs[0].plot(t, [r["loss"] for r in h], "o-", ms=3)
    axs[0].set_ylabel("loss (goal)")
    axs[1].plot(t, [r["metrics"]["beam_width_deg"] for r in h], "o-", ms=3)
    axs[1].set_ylabel("-6 dB beam width (deg)")
    axs[2].plot(t, [r["metrics"]["on_axis_db"] for r in h], "o-", ms=3)
    axs[2].set_ylabel("on-axis gain re bare (dB)")
    for a in axs:
        a.set_xlabel("wall time (s)")
        a.grid(True, alpha=0.3)
    fig.suptitle(result.goal, fontsize=9)
    fig.tight_layout()
    return fig


def fields_plot(problem: DesignProblem, designs: dict, *, frame_fraction: float = 0.55):
    """Field snapshot (grey, as the paper) and peak level (dB) of each design."""
    import matplotlib.pyplot as plt

    from .. import plots

    g = problem.grid
    n = len(designs)
    fig, axs = plt.subplots(2, n, figsize=(5.5 * n, 2 * 5.5 * g.shape[1] / g.shape[0] + 1.5), squeeze=False)
    every = max(1, int(round(g.cells_per_wavelength * SPEED_OF_SOUND_20C_M_S / g.c_max_m_s / 8)))
    k = max(1, problem.n_steps // 40)
    for j, (label, params) in enumerate(designs.items()):
        snaps, steps, pmax = problem.fields(params, k)
        i = int(np.argmin(np.abs(steps - frame_fraction * problem.n_steps)))
        occ = None if params is None else np.asarray(problem.occupancy(params))
        plots.field_image(
            snaps[i],
            g.dx_m,
            every=every,
            step=int(steps[i]),
            dt_s=g.dt_s,
            obstacles=occ,
            sources=[problem.source().cells_array],
            title=label,
            ax=axs[0, j],
        )
        db = 20 * np.log10(np.maximum(pmax / max(float(pmax.max()), 1e-30), 1e-3))
        axs[1, j].imshow(
            db.T,
            origin="lower",
            cmap="magma",
            vmin=-60,
            vmax=0,
            extent=[0, g.shape[0] * g.dx_m * 1e3, 0, g.shape[1] * g.dx_m * 1e3],
        )
        if occ is not None:
            x, y = (np.arange(m) * g.dx_m * 1e3 for m in g.shape)
            axs[1, j].contour(x, y, occ.T, levels=[0.5], colors="cyan", linewidths=0.8)
        axs[1, j].set_title(f"{label}: peak level (dB, 60 dB range)", fontsize=9)
        axs[1, j].set_xlabel("x (mm)")
    fig.tight_layout()
    return fig


def patterns_plot(problem: DesignProblem, patterns: dict, *, title: str):
    from .. import plots

    ref = max(float(np.abs(np.asarray(p)).max()) for p in patterns.values())
    a = np.asarray(problem.angles_deg)
    sel = np.abs(a) <= 90
    curves = {k: _levels_db(p, ref)[sel] for k, p in patterns.items()}
    return plots.lobe_plots(a[sel], curves, floor_db=-50.0, title=title)


def machine_info() -> dict:
    import jax

    return {
        "date_utc": time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime()),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": __import__("os").cpu_count(),
        "devices": [str(d) for d in jax.devices()],
    }


def _json_default(o: object) -> float | str:
    """JSON of what `json` cannot write: NumPy real scalars as floats, anything else as its str."""
    if isinstance(o, (np.integer, np.floating, np.bool_)):
        return float(o)
    return str(o)


def write_json(path: Path, data: dict) -> Path:
    path.write_text(json.dumps(data, indent=2, default=_json_default) + "\n")
    return path


def fmt_metrics(m: dict, sector_deg: float = 10.0) -> str:
    return (
        f"-6 dB width {m['beam_width_deg']:.2f} deg, on-axis gain {m['on_axis_db']:+.2f} dB, "
        f"side lobe {m['sidelobe_db']:.1f} dB, DI {m['directivity_db']:.2f} dB, "
        f"power within ±{sector_deg:g} deg {100 * m['sector_fraction']:.1f} %"
    )
