"""Optimise a design with optimistix BFGS through the checkpointed simulation.

The optimiser works on the unconstrained vector u of `limits.unpack` (sigmoids / tanh), so every
iterate is an admissible shape; parameters not listed in `free` stay at their start values. The
loop calls the solver's `init`/`step`/`terminate` one step at a time, so progress is shown
(tqdm) and the design accepted at every step is recorded with its wall time; the best one is
returned.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import equinox as eqx
import jax
import jax.numpy as jnp

from .objectives import Goal
from .problem import DesignProblem
from .shapes import DesignParams


@dataclass
class DesignResult:
    """Start and best designs, their measures, and the accepted design at every step."""

    start: DesignParams
    best: DesignParams
    metrics_start: dict
    metrics_best: dict
    loss_start: float
    loss_best: float
    history: list[dict] = field(default_factory=list)
    n_steps: int = 0
    wall_s: float = 0.0
    converged: bool = False
    goal: str = ""

    def summary(self) -> dict:
        return {
            "goal": self.goal,
            "start": self.start.as_dict(),
            "best": self.best.as_dict(),
            "metrics_start": self.metrics_start,
            "metrics_best": self.metrics_best,
            "loss_start": self.loss_start,
            "loss_best": self.loss_best,
            "optimiser_steps": self.n_steps,
            "recorded_steps": len(self.history),
            "wall_s": self.wall_s,
            "converged": self.converged,
        }


def _floats(d: dict) -> dict:
    return {k: float(v) for k, v in d.items()}


def optimise(
    problem: DesignProblem,
    start,
    goal: Goal,
    *,
    free: tuple[str, ...] | None = None,
    max_steps: int = 20,
    rtol: float = 1e-4,
    atol: float = 1e-4,
    first_step: float = 0.5,
    progress: bool = True,
) -> DesignResult:
    """Minimise `goal.loss(problem.metrics(design))` (plus the constraints' penalties) from `start` over the `free` parameters
    (default: all) with BFGS; returns a `DesignResult` (best accepted design). The loss is scaled
    so that the first step moves u (the sigmoid/tanh arguments) by `first_step`. `history` lists
    the accepted iterates (a step whose trial point the line search rejects repeats the last one)."""
    import optimistix as optx
    from tqdm.auto import tqdm

    limits = problem.limits
    names = type(start).NAMES
    free = tuple(names if free is None else free)
    unknown = [n for n in free if n not in names]
    if unknown or not free:
        raise ValueError(f"free = {free}: choose among {', '.join(names)}")
    idx = jnp.array([names.index(n) for n in free])
    u_all = limits.pack(problem.check(start))

    def unpack(v):
        return limits.unpack(u_all.at[idx].set(v))

    v0 = u_all[idx]

    def raw(v):
        params = unpack(v)
        m = problem.metrics(params)
        return goal.loss(m) + problem.penalty(params), (m, params)

    def fn(v, scale):
        loss, (m, params) = raw(v)
        return scale * loss, (loss, m, params)

    solver: optx.BFGS = optx.BFGS(rtol=rtol, atol=atol)  # generic in (Y, Aux, Hessian): left open
    one = jnp.asarray(1.0, v0.dtype)
    f_struct, aux_struct = eqx.filter_eval_shape(fn, v0, one)
    step = eqx.filter_jit(lambda v, s, a: solver.step(fn, v, a, {}, s, frozenset()))
    done = eqx.filter_jit(lambda v, s, a: solver.terminate(fn, v, a, {}, s, frozenset()))
    t0 = time.perf_counter()
    # scale the loss so that BFGS's first step (identity Hessian: minus the gradient) is
    # `first_step` long in u: one unscaled step gives the gradient at the start (same compiled step)
    state = solver.init(fn, v0, one, {}, f_struct, aux_struct, frozenset())
    _, state, _ = step(v0, state, one)
    g0 = float(jnp.linalg.norm(state.f_info.grad))
    scale = jnp.asarray(first_step / max(g0, 1e-30), v0.dtype)
    state = solver.init(fn, v0, scale, {}, f_struct, aux_struct, frozenset())

    history: list[dict] = []
    v = v0
    bar = tqdm(total=max_steps, desc=f"design {problem.kind}", disable=not progress, leave=False)
    converged = False
    n = 0
    for n in range(1, max_steps + 1):
        v, state, (loss, m, params) = step(v, state, scale)
        rec = {
            "step": n,
            "wall_s": time.perf_counter() - t0,
            "loss": float(loss),
            "metrics": _floats(m),
            "params": params.as_dict(),
        }
        history.append(rec)
        bar.update(1)
        bar.set_postfix(
            loss=f"{rec['loss']:.4g}",
            width=f"{rec['metrics']['beam_width_deg']:.2f}",
            gain=f"{rec['metrics']['on_axis_db']:.2f}",
        )
        stop, _ = done(v, state, scale)
        if bool(stop):
            converged = True
            break
    bar.close()
    wall = time.perf_counter() - t0
    finite = [h for h in history if math.isfinite(h["loss"])]
    if not finite:
        raise FloatingPointError("every accepted design gave a non-finite loss")
    best = min(finite, key=lambda h: h["loss"])
    first = history[0]  # the first step accepts the start point
    best_params = type(start)(**best["params"])
    return DesignResult(
        start=start,
        best=best_params,
        metrics_start=first["metrics"],
        metrics_best=best["metrics"],
        loss_start=first["loss"],
        loss_best=best["loss"],
        history=history,
        n_steps=n,
        wall_s=wall,
        converged=converged,
        goal=goal.describe(),
    )


def gradient_check(
    problem: DesignProblem, params, quantity: str | Goal = "beam_width_deg", *, rel_steps=None
) -> list[dict]:
    """Gradient of one beam measure (or a `Goal`'s loss) w.r.t. every design parameter against
    central differences.

    Each parameter p gets a step h (default 1e-4 cells for lengths, 1e-4 for the flare); the
    central difference D(h) has truncation error ~ h^2 f''' / 6, estimated by Richardson as
    |D(2h) - D(h)| / 3. Returns rows with the analytic and finite-difference values, their
    difference and that estimate."""

    def value(p):
        m = problem.metrics(p)
        return quantity.loss(m) if isinstance(quantity, Goal) else m[quantity]

    f = jax.jit(value)
    g = eqx.filter_jit(eqx.filter_grad(value))(params)
    rows = []
    dx = problem.grid.dx_m
    for name in type(params).NAMES:
        h = (rel_steps or {}).get(name, 1e-4 if name == "flare" else 1e-4 * dx)

        def at(d, name=name):
            return float(f(eqx.tree_at(lambda p: getattr(p, name), params, getattr(params, name) + d)))

        d1 = (at(h) - at(-h)) / (2 * h)
        d2 = (at(2 * h) - at(-2 * h)) / (4 * h)
        ga = float(getattr(g, name))
        rows.append(
            {
                "parameter": name,
                "step": h,
                "grad": ga,
                "fd": d1,
                "abs_error": abs(ga - d1),
                "fd_truncation_estimate": abs(d2 - d1) / 3,
                "rel_error": abs(ga - d1) / max(abs(d1), 1e-300),
            }
        )
    return rows
