"""The fit as a program: a config's data loaded, the transfer simulated (with the error
budget's second resolution prefetched in a background thread), the model families' stages run,
the error budget and the report written, provenance recorded, the console summary and the exit
code (`run_fit`, `run_fit_config`; `difflattice fit` calls them). The library it drives is
`difflattice.fit`."""

from __future__ import annotations

import dataclasses
import time
import warnings
from pathlib import Path
from typing import Any, cast

from ..config import ConfigWarning, message, show, specs
from ..fit.config import FitConfig, SolverSection, load_config
from ..fit.loading import fit_air, load_fit_data
from .provenance import provenance


def fit_options(cfg: FitConfig):
    """The solver's `FitOptions` for `cfg`. The robust-loss and convergence keys are passed on
    where this version's `FitOptions` accepts them; a non-default value it does not accept gives
    a `ConfigWarning`."""
    from ..fit.solve import FitOptions

    s = cfg.solver
    kw: dict[str, Any] = dict(
        solver=s.name,
        rtol=s.rtol,
        atol=s.atol,
        max_steps=s.max_steps,
        floor_db=s.floor_db,
        lobe_weight=s.lobe_weight,
        wave_weight=s.wave_weight,
    )
    accepted = {f.name for f in dataclasses.fields(FitOptions)}
    newer = {"loss": s.loss, "loss_scale": s.loss_scale, "rtol_cost": s.rtol_cost, "rtol_step": s.rtol_step}
    defaults = {sp.name: sp.default for sp in specs(SolverSection)}
    for k, v in newer.items():
        if k in accepted:
            kw[k] = v
        elif v != defaults[k]:
            warnings.warn(
                message(
                    cfg.path, f"solver.{k}", None, f"= {show(v)} is ignored: this version's solver does not support it"
                ),
                ConfigWarning,
                stacklevel=2,
            )
    try:
        return FitOptions(**kw)
    except ValueError as e:
        raise cfg.error("solver", str(e)) from None


def _warn_unused_uncertainty(cfg: FitConfig) -> None:
    """[uncertainty] is declared for the error budget (`fit.uncertainty`); where this version has
    no such module, a key that is set is said to be unused rather than silently ignored."""
    import importlib.util

    u = cfg.uncertainty
    given = {
        k: v
        for k, v in (
            ("second_cells_per_wavelength", u.second_cells_per_wavelength),
            ("model_families", u.model_families),
        )
        if v not in (None, ())
    }
    if given and importlib.util.find_spec("difflattice.fit.uncertainty") is None:
        for k, v in given.items():
            warnings.warn(
                message(
                    cfg.path,
                    f"uncertainty.{k}",
                    None,
                    f"= {show(v)} is not used: this version has no uncertainty budget (fit.uncertainty)",
                ),
                ConfigWarning,
                stacklevel=3,
            )


def _fit_line(cfg: FitConfig, lobe, wave, f: float, c: float, ppw: float, opts, verbose: bool, prefetch):
    """The line model's transfer, fit and untuned uniform fit: (fitted, uniform, transfer,
    make_transfer(cells_per_wavelength), transfer time in s). `prefetch`: a resolution (cells per
    wavelength) whose transfer the error budget will ask for, simulated beside the fit (or None)."""
    from ..fit.families import shared_family
    from ..fit.model import ModelSpec
    from ..fit.solve import fit
    from ..fit.transfer import free_field_transfer

    m = cfg.model
    dx = c / (f * ppw)
    n_cells = int(round(m.line_length_m / dx))
    if n_cells < 3:
        raise cfg.error(
            "model.line_length_m",
            f"= {show(m.line_length_m)} m is {n_cells} cells at {ppw:g} cells per "
            f"wavelength ({dx * 1e3:.2f} mm); the line needs >= 3 cells; fix: give the face length in metres",
        )

    def simulate_transfer(cpw: float):
        return free_field_transfer(
            frequency_hz=f,
            c_m_s=c,
            n_cells=int(round(m.line_length_m / (c / (f * cpw)))),
            cells_per_wavelength=cpw,
            lobe_angle_deg=None if lobe is None else lobe.angle_deg,
            lobe_range_m=None if lobe is None else (m.lobe_range_m or lobe.range_m),
            wave_x_m=None if wave is None else wave.x_m,
            wave_z_m=None if wave is None else wave.z_m,
        )

    t0 = time.perf_counter()
    transfer = simulate_transfer(ppw)
    t_transfer = time.perf_counter() - t0
    make_transfer = _Prefetched(simulate_transfer, prefetch)
    try:
        spec = ModelSpec(
            n_cells=n_cells,
            dx_m=dx,
            frequency_hz=f,
            weights=cast(Any, m.weights),  # checked against PROFILES by the declaration
            lags=cast(Any, m.lags),
            n_basis=m.n_basis,
            symmetric=m.symmetric,
            fit_diameter=m.fit_diameter,
            diameter_m=m.diameter_m,
        )
    except ValueError as e:
        raise cfg.error("model", str(e)) from None
    # a given diameter is the start of a fitted one (no scan over diameters)
    params0 = spec.init_params() if (m.fit_diameter and m.diameter_m is not None) else None
    uspec = ModelSpec(
        n_cells=n_cells,
        dx_m=dx,
        frequency_hz=f,
        weights="uniform",
        lags="uniform",
        fit_diameter=False,
        diameter_m=m.diameter_m or m.line_length_m,
    )
    uniform = _beside(fit, uspec, transfer, lobe, wave, opts)
    fitted = fit(
        spec, transfer, lobe, wave, opts, progress=verbose, params0=params0, multistart=True,
        solve_in=shared_family(spec, opts, list(cfg.uncertainty.model_families) or None),
    )  # fmt: skip
    return fitted, uniform.result(), transfer, make_transfer, t_transfer


def _beside(fn, *args):
    """`fn(*args)` in a thread from now on (`.result()` waits for it and raises its error): the
    untuned uniform fit beside the main fit, which does not need it. On a first run XLA compiles
    the two fits' programs on two cores (compilation releases the GIL); the results are the same
    as one after the other (independent programs)."""
    import concurrent.futures

    pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="difflattice-uniform-fit")
    future = pool.submit(fn, *args)
    pool.shutdown(wait=False)
    return future


class _Prefetched:
    """`make_transfer` with the transfer at one resolution (`cells_per_wavelength`; None: none)
    simulated in a background thread from now on: the error budget's second resolution runs while
    the main fit traces its programs (one core each; the native kernels and XLA release the GIL).
    A call for that resolution waits for the thread and returns its result (or raises its error)."""

    def __init__(self, make, cells_per_wavelength: float | None):
        import concurrent.futures

        self.make = make
        self.cpw = cells_per_wavelength
        self.future = None
        if cells_per_wavelength is not None:
            pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="difflattice-prefetch")
            self.future = pool.submit(make, cells_per_wavelength)
            pool.shutdown(wait=False)

    def __call__(self, cells_per_wavelength: float):
        if self.future is not None and cells_per_wavelength == self.cpw:
            return self.future.result()
        return self.make(cells_per_wavelength)


def _fit_disc(cfg: FitConfig, lobe, wave, f: float, c: float, ppw: float, opts, verbose: bool, prefetch):
    """The disc model's (`fit.disc`) transfer on the axisymmetric lattice, fit and untuned uniform
    piston fit, as `_fit_line`; `line_length_m` is the modelled disc's diameter."""
    from ..fit.families import shared_family
    from ..fit.solve import fit
    from ..fit.transfer_disc import disc_setup

    m = cfg.model
    t0 = time.perf_counter()
    try:
        setup = disc_setup(
            frequency_hz=f,
            c_m_s=c,
            face_diameter_m=m.line_length_m,
            cells_per_wavelength=ppw,
            lobe=lobe,
            wave=wave,
            lobe_range_m=m.lobe_range_m,
            weights=m.weights,
            lags=m.lags,
            n_basis=m.n_basis,
            fit_diameter=m.fit_diameter,
            diameter_m=m.diameter_m,
            baffle=m.baffle,
            can_depth_m=m.can_depth_m,
            can_wall_m=m.can_wall_m,
            stencil=cast(Any, m.stencil),  # checked against the choices by the declaration
        )
    except ValueError as e:
        raise cfg.error("model", str(e)) from None
    t_transfer = time.perf_counter() - t0
    make_transfer = _Prefetched(setup.make_transfer, prefetch)
    spec, transfer = setup.spec, cast(Any, setup.transfer)  # a DiscTransfer: the interface of a Transfer
    params0 = spec.init_params() if (m.fit_diameter and m.diameter_m is not None) else None
    uniform = _beside(fit, setup.uniform_spec, transfer, lobe, wave, opts)
    fitted = fit(
        spec, transfer, lobe, wave, opts, progress=verbose, params0=params0, multistart=True,
        solve_in=shared_family(spec, opts, list(cfg.uncertainty.model_families) or None),
    )  # fmt: skip
    return fitted, uniform.result(), transfer, make_transfer, t_transfer


def run_fit(cfg: FitConfig, *, out: str | Path | None = None, quick: bool = False, verbose: bool = True) -> dict:
    """Run a checked config; returns the report dict (also written to the output dir).

    Data problems are `ConfigError`s naming the key (see `load_fit_data`). Uses the JAX precision
    the caller set (float64 expected; see the module docstring)."""
    import jax

    if not jax.config.read("jax_enable_x64"):
        warnings.warn(
            "run_fit: JAX runs in float32 (jax_enable_x64 is off); fits expect float64: call "
            "jax.config.update('jax_enable_x64', True) at start-up",
            RuntimeWarning,
            stacklevel=2,
        )
    from ..fit.figures import prestart_worker
    from ..fit.report import start_figures, write_report

    prestart_worker()  # the report's figure worker imports matplotlib beside the fit
    data = load_fit_data(cfg)
    lobe, wave, f = data.lobe, data.wave, data.frequency_hz
    air_used = fit_air(cfg, data)
    c = air_used["speed_of_sound_m_s"]
    if verbose:
        print(
            f"air: {air_used['temperature_c']:.2f} degC, {air_used['humidity_pct']:g} % RH, "
            f"{air_used['pressure_pa']:.0f} Pa -> c = {c:.2f} m/s (from {air_used['source']})"
        )
    m = cfg.model
    ppw = 12.0 if quick else m.cells_per_wavelength
    opts = fit_options(cfg)
    _warn_unused_uncertainty(cfg)
    fit_model = _fit_disc if m.model == "disc" else _fit_line
    # the error budget's second resolution (as `error_budget` picks it), simulated beside the fit
    from ..fit.uncertainty import error_budget, second_resolution

    m2 = second_resolution(ppw, None if quick else cfg.uncertainty.second_cells_per_wavelength)
    fitted, uniform, transfer, make_transfer, t_transfer = fit_model(cfg, lobe, wave, f, c, ppw, opts, verbose, m2)
    fitted.warnings[:0] = [f"data: {n}" for n in data.notes]
    out_dir = Path(out) if out is not None else Path(cfg.output.dir)
    # the figures that do not need the error budget are drawn in a worker process meanwhile
    field_image = cfg.output.field_image and not quick  # a line on the 2-D lattice, a disc on the rz lattice
    figures = start_figures(out_dir, fitted, uniform, transfer, lobe, wave, field_image=field_image)
    # error budget (fit.uncertainty): refits at a second resolution and with other model families
    t1 = time.perf_counter()
    try:
        budget = error_budget(
            fitted,
            transfer,
            lobe,
            wave,
            opts,
            make_transfer=make_transfer,
            second_cells_per_wavelength=None if quick else cfg.uncertainty.second_cells_per_wavelength,
            model_families=list(cfg.uncertainty.model_families) or None,
            progress=verbose,
        )
    except BaseException:
        figures.close()
        raise
    t_budget = time.perf_counter() - t1
    prov = provenance(cfg.path if cfg.path is not None and cfg.path.exists() else None, data.paths)
    prov["timing_s"] = {
        "transfer_simulation": t_transfer,
        "fit": fitted.wall_time_s,
        "total_to_fit": t_transfer + fitted.wall_time_s,
        "error_budget": t_budget,
    }
    prov["quick"] = quick
    prov["temperature_c"] = data.temperature_c
    prov["speed_of_sound_m_s"] = c
    prov["air"] = air_used
    prov["data_notes"] = list(data.notes)
    rep = write_report(
        out_dir,
        fitted,
        uniform,
        transfer,
        lobe,
        wave,
        provenance=prov,
        field_image=field_image,
        budget=budget,
        figures=figures,
    )
    if verbose:
        _print_summary(rep, out_dir)
    return rep


def _print_summary(rep: dict, out_dir: Path) -> None:
    f = rep["fit"]
    verdict = f["outcome"]
    if verdict["outcome"] != "consistent":
        print("!" * 72 + f"\n!! {verdict['line']}\n" + "!" * 72)
    for w in f["warnings"]:
        print(f"warning: {w}")
    p = f["parameters"]
    units = {"lobe_db": "dB", "wave_phase_deg": "deg"}
    rms = ", ".join(
        f"{k} {v:.3g} {units.get(k, '')}".rstrip()
        for k, v in f["rms"].items()
        if "normalised" not in k and "all_points" not in k
    )
    t = rep["provenance"]["timing_s"]
    d = next((e for e in rep.get("budget", {}).get("scalars", []) if e["name"] == "diameter_mm"), None)
    dtxt = (
        f"{p['diameter_m'] * 1e3:.3f} (fixed)"
        if d is None
        else f"{d['limit']} ({d['status']})"
        if d["status"] == "at_bound"
        else f"{d['value']:.3f} ({d['status']}: {d['note']})"
        if d["status"] != "determined"
        else f"{d['value']:.4g} ± {d['stat']:.2g} (stat) ± {d['systematic']:.2g} (sys) = ± {d['total']:.2g}"
    )
    print(
        f"fit: {f['result_code']} in {f['n_steps']} steps; D = {dtxt} mm; RMS {rms}; {_chi2_text(f)}; "
        f"transfer {t['transfer_simulation']:.1f} s + fit {t['fit']:.1f} s + error budget {t.get('error_budget', 0):.1f} s"
    )
    for u in rep.get("budget", {}).get("undetermined", []):
        print(f"not determined by the data: {u}")
    print(f"report: {out_dir / 'report.md'}")
    print(f"{verdict['outcome'].replace('_', ' ')} (exit {verdict['exit_code']}): {verdict['line']}")


def _chi2_text(f: dict) -> str:
    """'chi2_red 0.98 (p 0.61; lobe 1.0, wave 0.93)': per measured datum, joint and per data set."""
    g = f.get("goodness") or {}
    j = g.get("joint")
    if j is None:
        return f"chi2_red {f['chi2_reduced']:.3g}"
    sets = ", ".join(f"{k} {g[k]['chi2_reduced']:.3g}" for k in ("lobe", "wave") if k in g)
    return f"chi2_red {j['chi2_reduced']:.3g} (p {j['p']:.2g}; {sets})"


def run_fit_config(path: str | Path, *, out=None, quick: bool = False) -> int:
    """`difflattice fit`: load, run, report; exit code 0 (converged and consistent with the data),
    3 (did not converge) or 4 (converged, but the model does not describe the data): see
    `fit.verdict`. A housed-transducer config (`[model] model = "housed"`) runs `fitting_housed`."""
    from ..fit.housed_config import is_housed_config

    if is_housed_config(path):
        from .fitting_housed import run_housed_config

        return run_housed_config(path, out=out, quick=quick)
    cfg = load_config(path)
    rep = run_fit(cfg, out=out, quick=quick)
    return int(rep["fit"]["outcome"]["exit_code"])
