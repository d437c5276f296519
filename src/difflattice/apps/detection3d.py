"""The detection map of a 3-D pulse-echo scene at several transducer poses: the scene run once
per pose, each surface's first-echo level (dB re the transmit peak, `echoes3d.label_echoes`)
against the detection thresholds."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .echoes3d import THRESHOLDS_DB


def detection_map(path, poses, out_dir, *, quiet: bool = True) -> dict[str, Any]:
    """Run the 3-D pulse-echo scene file `path` once per transducer pose and write the detection
    map: per pose (``(x_m, y_m, yaw_deg)``: the transducer's centre in the floor plane and its
    axis turned by yaw from +x towards +y, height kept) each surface's first-echo level (dB re the
    transmit peak), its error against the lattice delay, and which thresholds it clears.
    Writes OUT/detection_map.json and detection_map.png; returns the map."""
    import json
    from dataclasses import replace
    from pathlib import Path

    from ..scene.model import SceneError, load_scene
    from ..scene.schema import DiscTransducer
    from .scene3d_run import run_scene3d, write_outputs3d

    base = load_scene(path)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for i, (x_m, y_m, yaw_deg) in enumerate(poses):
        t = base.transducers[0]
        if not isinstance(t, DiscTransducer):
            raise SceneError(f"{path}: [transducers[0].type] = {t.type!r}: a 3-D pulse-echo scene has a disc")
        a = math.radians(float(yaw_deg))
        t = replace(t, centre_m=(float(x_m), float(y_m), float(t.centre_m[2])), axis=(math.cos(a), math.sin(a), 0.0))
        scene = replace(base, transducers=(t, *base.transducers[1:]))
        sr = run_scene3d(scene, quiet=quiet)
        write_outputs3d(sr, out / f"pose{i}")
        table = json.loads((out / f"pose{i}" / "echoes.json").read_text())
        rows.append({"pose": {"x_m": x_m, "y_m": y_m, "yaw_deg": yaw_deg}, "echoes": table["echoes"]})
    doc = {"scene": str(path), "thresholds_db": list(THRESHOLDS_DB), "poses": rows}
    (out / "detection_map.json").write_text(json.dumps(doc, indent=1, default=float))
    _plot_map(doc, out / "detection_map.png")
    return doc


def _plot_map(doc: dict, path):
    """Surfaces (rows) x poses (columns), coloured by echo level, the level written in each."""
    from matplotlib.figure import Figure

    from .. import plots

    names = sorted({e["surface"] for p in doc["poses"] for e in p["echoes"]})
    level = np.full((len(names), len(doc["poses"])), np.nan)
    for j, p in enumerate(doc["poses"]):
        for e in p["echoes"]:
            level[names.index(e["surface"]), j] = e.get("level_db", np.nan)  # none: after the record's end
    fig = Figure(figsize=(2 + 1.6 * len(doc["poses"]), 1 + 0.45 * len(names)))
    ax = fig.add_subplot()
    im = ax.imshow(level, vmin=-80, vmax=0, cmap="viridis", aspect="auto")
    for (r, c), v in np.ndenumerate(level):
        if np.isfinite(v):
            ax.text(c, r, f"{v:.0f}", ha="center", va="center", fontsize=8, color="w" if v < -40 else "k")
    ax.set_yticks(range(len(names)), names, fontsize=8)
    labels = [
        f"({p['pose']['x_m']:.2f}, {p['pose']['y_m']:.2f}) m\nyaw {p['pose']['yaw_deg']:g} deg" for p in doc["poses"]
    ]
    ax.set_xticks(range(len(labels)), labels, fontsize=8)
    fig.colorbar(im, ax=ax, label="first-echo level (dB re transmit peak)")
    ax.set_title(
        f"detection map: detected where above the threshold ({', '.join(f'{t:g}' for t in doc['thresholds_db'])} dB)"
    )
    fig.tight_layout()
    return plots.save(fig, path)
