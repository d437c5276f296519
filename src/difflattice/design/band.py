"""Broadband design: the same horn designed at the carrier alone and over the drive burst's band,
both re-simulated with the burst and compared frequency by frequency (`difflattice design compare`).

A band problem (`horn_design(band="burst")`) records the contour pressures of each run and takes
their DFT at frequencies across the burst's -6 dB band (`problem.band_frequencies`); its beam is
the burst's energy pattern sqrt(sum_k w_k |p_k(theta)|^2) (w_k the burst's energy density at
f_k), so its -6 dB width, side-lobe level and gain are those of the echo energy a receiver sees,
not of the carrier alone. The carrier-only design optimises the same goal on the carrier's
pattern. Both designs are then run again in the band problem (the same burst) and their widths
at every band frequency and of the energy pattern are tabled.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax
import numpy as np

from .constraints import MakerConstraints, limits_for, project
from .objectives import Goal, pattern_metrics
from .optimise import optimise
from .presets import FIG09_CONE, HORN_CONSTRAINTS, HORN_LIMITS, PAPER_FACE_M
from .problem import DesignProblem, horn_design
from .report import write_json
from .study import trust_estimate, trust_line


def band_table(problem: DesignProblem, designs: dict) -> dict:
    """Per design: the -6 dB width and on-axis gain (re the bare transducer at the same frequency)
    at each of the band problem's frequencies, and the energy pattern's measures."""
    pats_bare = np.asarray(jax.jit(lambda: problem.band_patterns(None))())
    i0 = problem.angles_deg.index(0.0)
    out: dict = {"frequencies_hz": list(problem.frequencies_hz), "weights": list(problem.band_weights)}
    for label, params in designs.items():
        pats = np.asarray(jax.jit(problem.band_patterns)(params))
        per = []
        for k in range(len(problem.frequencies_hz)):
            m = pattern_metrics(pats[k], problem.angles_deg, reference_on_axis=abs(pats_bare[k, i0]))
            per.append({"beam_width_deg": float(m["beam_width_deg"]), "on_axis_db": float(m["on_axis_db"])})
        energy = {k: float(v) for k, v in problem.metrics(params).items()}
        out[label] = {"per_frequency": per, "energy": energy, "params": params.as_dict()}
    return out


def verdict(table: dict, a: str, b: str) -> str:
    """Which of two designs is narrower over the band: by the energy pattern's width and by how
    many band frequencies each is the narrower at."""
    wa, wb = table[a]["energy"]["beam_width_deg"], table[b]["energy"]["beam_width_deg"]
    na = sum(
        x["beam_width_deg"] < y["beam_width_deg"] for x, y in zip(table[a]["per_frequency"], table[b]["per_frequency"])
    )
    n = len(table["frequencies_hz"])
    narrower = a if wa < wb else b
    return (
        f"over the burst's band the {narrower} design is narrower: energy-pattern -6 dB width {a} {wa:.2f} deg, "
        f"{b} {wb:.2f} deg; {a} narrower at {na} of {n} band frequencies, {b} at {n - na}"
    )


def markdown(s: dict) -> str:
    t = s["table"]
    a, b = "carrier-only", "broadband"
    lines = [
        f"# {s['title']}",
        "",
        f"Goal: {s['goal']}; free: {', '.join(s['free'])}. Both designs re-simulated with the same "
        f"{s['cycles']:g}-cycle burst; widths at each band frequency and of the burst's energy pattern.",
        "",
        f"- {trust_line(s['trust'])} (at the band's top frequency)",
        f"- carrier-only: {s['steps'][a]} BFGS steps, converged: {s['converged'][a]}; broadband: "
        f"{s['steps'][b]} steps, converged: {s['converged'][b]}",
        "",
        f"| frequency (kHz) | burst weight | {a} width (deg) | {b} width (deg) | {a} gain (dB) | {b} gain (dB) |",
        "|---|---|---|---|---|---|",
    ]
    for k, f in enumerate(t["frequencies_hz"]):
        pa, pb = t[a]["per_frequency"][k], t[b]["per_frequency"][k]
        lines.append(
            f"| {f / 1e3:.2f} | {t['weights'][k]:.3f} | {pa['beam_width_deg']:.2f} | {pb['beam_width_deg']:.2f} | "
            f"{pa['on_axis_db']:+.2f} | {pb['on_axis_db']:+.2f} |"
        )
    ea, eb = t[a]["energy"], t[b]["energy"]
    lines += [
        f"| burst energy | 1 | {ea['beam_width_deg']:.2f} | {eb['beam_width_deg']:.2f} | {ea['on_axis_db']:+.2f} | "
        f"{eb['on_axis_db']:+.2f} |",
        "",
        s["verdict"],
        "",
        "| design | " + " | ".join(t[a]["params"]) + " |",
        "|---|" + "---|" * len(t[a]["params"]),
    ]
    for label in (a, b):
        lines.append(f"| {label} | " + " | ".join(f"{v:.5g}" for v in t[label]["params"].values()) + " |")
    return "\n".join(lines) + "\n"


def compare_band(
    out: str | Path,
    *,
    cells_per_wavelength: float = 8.0,
    target_deg: float = 8.0,
    wall: str = "soft",
    steps: int = 15,
    band="burst",
    constraints: MakerConstraints | None = None,
    lattice: str = "2d",
    progress: bool = True,
) -> dict:
    """The Fig. 9 cone optimised for a `target_deg` -6 dB width at the carrier and over `band`,
    both re-simulated with the burst; writes `compare.json` and `compare.md` to `out`."""
    c = HORN_CONSTRAINTS if constraints is None else constraints
    limits = limits_for(c, HORN_LIMITS)
    kw: dict[str, Any] = dict(
        limits=limits,
        face_m=PAPER_FACE_M,
        cells_per_wavelength=cells_per_wavelength,
        wall=wall,
        cycles=5.0,
        constraints=c,
        lattice=lattice,
    )
    carrier = horn_design(**kw)
    broad = horn_design(**kw, band=band)
    goal = Goal(width_target_deg=target_deg, width_weight=1.0, width_scale_deg=1.0)
    start = project(limits, FIG09_CONE)
    free = ("mouth_m", "length_m", "flare")
    res = {
        "carrier-only": optimise(carrier, start, goal, free=free, max_steps=steps, progress=progress),
        "broadband": optimise(broad, start, goal, free=free, max_steps=steps, progress=progress),
    }
    table = band_table(broad, {k: r.best for k, r in res.items()})
    trust = trust_estimate(broad)
    s = {
        "title": f"Horn for a {target_deg:g} deg beam: carrier-only vs the burst's band",
        "goal": goal.describe(),
        "free": list(free),
        "cycles": broad.cycles,
        "trust": trust,
        "steps": {k: r.n_steps for k, r in res.items()},
        "converged": {k: r.converged for k, r in res.items()},
        "table": table,
        "verdict": verdict(table, "carrier-only", "broadband"),
    }
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "compare.json", s)
    (out / "compare.md").write_text(markdown(s))
    return s
