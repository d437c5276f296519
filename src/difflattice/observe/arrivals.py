"""Arrival times of overlapping echoes: a sum of delayed, scaled copies of a known pulse fitted to a
trace (NumPy/SciPy; samples as the time unit).

An envelope peak reads one time from a window, wherever several arrivals overlap in it (an edge's
echo and the multiple of a recess a few periods behind it) the peak is theirs together, and
nothing says so. Here the trace x within a window is modelled as

    x(t) ~ Re sum_k A_k a(t - tau_k),      a = s + i H s  (the pulse's analytic signal),

K copies of the pulse s (the drive as the lattice carries it to the receiver: a model echo, or a
free-field trace) with delays tau_k (samples, free, fractional: shifted in the spectrum) and complex
amplitudes A_k (free: a reflection's or an edge's constant phase and its level). The amplitudes
enter linearly and are solved for each set of delays (variable projection); the delays by
Levenberg-Marquardt from the caller's predictions (image-source, edge, multiple paths). The free
phase makes the delays rest on the pulse's envelope, where the time of flight is (a carrier's phase
moves with the phase velocity). Arrivals the caller did not predict are added one at a time (at the
residual's matched-filter envelope peak) while the Bayesian information criterion falls.

**Uncertainty.** The covariance of (delays, amplitudes) is s^2 (J^T J)^-1 at the optimum, with s^2 the
residual variance, scaled by the samples per independent sample of a band-limited residual,
1 / (2 B dt) with B the pulse's equivalent noise bandwidth (the residual lives in the pulse's band;
white noise would be 1). It is the statistical error of a model that fits; the model's own error
(a pulse shape that differs) shows in the residual and is reported (`residual_rel`).
**Resolution.** An order whose copies the data do not tell apart (two delays correlated by
|r| >= `max_corr`, 0.9 by default: a copy split in two to mimic a pulse a little wider than the
model) is not chosen; where such an order would win by the BIC it is reported
(`unresolved_better`): the echo's shape differs from the pulse's, or arrivals overlap within
the pulse's resolution, and the data cannot say which (an isolated edge's echo, one arrival with
the edge's band-smooth spectral factor, reads so). **Separable**: the first arrival is
significant (`min_significance` standard errors) and its standard error is below
`max_sigma_periods`; otherwise "not separable", with the reason. What no fit can do: an arrival
less than ~2 periods behind another reads as one copy between them whose residual stays small
(measured on synthetic overlaps, docs/three_d.md), so a fit can call such a pair separable; the
predicted paths say where to expect one.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

BIC_MARGIN = 10.0
"""A further arrival is kept when it lowers the BIC by more than this ("very strong" evidence on
Kass & Raftery's scale: a Bayes factor above ~150)."""


@dataclasses.dataclass(frozen=True)
class Arrival:
    """One fitted copy of the pulse: delay (samples) and its standard error, complex amplitude
    and its standard error (of |A|), the prediction it started from (None: added by the BIC)."""

    delay: float
    sigma_delay: float
    amplitude: complex
    sigma_amplitude: float
    predicted: float | None

    @property
    def significance(self) -> float:
        """|A| in standard errors."""
        return abs(self.amplitude) / max(self.sigma_amplitude, 1e-300)


@dataclasses.dataclass(frozen=True)
class ArrivalFit:
    """The fitted arrivals of one window (sorted by delay), the window [lo, hi) (samples), the
    residual's rms over the trace's rms in the window, the first arrival (the earliest whose
    amplitude is significant, `min_significance` standard errors), the correlation of its delay with
    each other delay, whether an order with unresolved copies would have won by the BIC (the
    echo's shape differs from the pulse's, or arrivals overlap within the pulse's resolution: the
    data cannot say which), and whether the first arrival is separable (module docstring)."""

    arrivals: tuple[Arrival, ...]
    lo: int
    hi: int
    residual_rel: float
    first: int
    first_corr: tuple[float, ...]
    unresolved_better: bool
    separable: bool
    why: str
    samples_per_period: float

    @property
    def first_arrival(self) -> Arrival:
        return self.arrivals[self.first]

    def as_dict(self) -> dict:
        """Plain fields for a JSON table; delays in samples."""
        f = self.first_arrival
        return {
            "delay_samples": f.delay,
            "sigma_samples": f.sigma_delay,
            "sigma_periods": f.sigma_delay / self.samples_per_period,
            "separable": self.separable,
            "why": self.why,
            "n_arrivals": len(self.arrivals),
            "arrivals": [
                {
                    "delay_samples": a.delay,
                    "sigma_samples": a.sigma_delay,
                    "amplitude": abs(a.amplitude),
                    "phase_rad": math.atan2(a.amplitude.imag, a.amplitude.real),
                    "significance": a.significance,
                    "predicted_samples": a.predicted,
                }
                for a in self.arrivals
            ],
            "first_corr": list(self.first_corr),
            "unresolved_better": self.unresolved_better,
            "residual_rel": self.residual_rel,
            "window_samples": [self.lo, self.hi],
        }


class Pulse:
    """A pulse `s` (samples) prepared for fractional shifts on traces of `n` samples: the analytic
    signal's spectrum on a zero-padded FFT grid (no wrap-around). A delay moves it from where it
    lies in `s` (a model echo already at its predicted delay is fitted for the excess alone)."""

    def __init__(self, s, n: int):
        s = np.asarray(s, float)
        if s.ndim != 1 or len(s) < 2 or not np.any(s):
            raise ValueError("the pulse must be a non-zero 1-D array of samples")
        self.n = int(n)
        self.n_fft = 1 << int(math.ceil(math.log2(2 * max(self.n, len(s)))))
        spec = np.fft.fft(s, self.n_fft)
        h = np.zeros(self.n_fft)
        h[0] = 1.0
        h[1 : self.n_fft // 2] = 2.0
        h[self.n_fft // 2] = 1.0
        self.spec = spec * h  # the analytic signal's spectrum
        self.w = 2 * np.pi * np.fft.fftfreq(self.n_fft)  # rad/sample
        e = np.abs(np.fft.ifft(self.spec)) ** 2
        lag = np.fft.fftfreq(self.n_fft, 1.0 / self.n_fft)  # sample index, negative ones wrapped
        self.centre = float((lag * e).sum() / e.sum())  # where the pulse's energy sits (samples)
        p = np.abs(spec[: self.n_fft // 2]) ** 2
        # equivalent noise bandwidth (cycles/sample, one-sided) of the pulse's band
        self.bandwidth = float(p.sum() ** 2 / (p**2).sum()) / self.n_fft
        self.offset = 0  # the trace's sample of this FFT grid's sample 0

    def around(self, lo: int, hi: int, margin: int) -> Pulse:
        """The same pulse on a shorter FFT grid holding samples [lo - margin, hi + margin) of the
        trace: shifts of up to `margin` samples into [lo, hi) come out as on the whole trace,
        for a fraction of the cost of an FFT over it."""
        a = np.fft.ifft(self.spec)
        s0, s1 = lo - margin, hi + margin
        out = object.__new__(Pulse)
        out.n = self.n
        out.n_fft = 1 << int(math.ceil(math.log2(s1 - s0)))  # a shift within the margin wraps nothing into the window
        out.spec = np.fft.fft(a[np.arange(s0, s1) % self.n_fft], out.n_fft)
        out.w = 2 * np.pi * np.fft.fftfreq(out.n_fft)
        out.centre, out.bandwidth, out.offset = self.centre, self.bandwidth, s0
        return out

    def shifted(self, tau: float, lo: int, hi: int) -> np.ndarray:
        """The analytic pulse delayed by `tau` samples, on the trace's samples [lo, hi)."""
        return np.fft.ifft(self.spec * np.exp(-1j * self.w * tau))[lo - self.offset : hi - self.offset]


def _design(pulse: Pulse, taus, lo: int, hi: int) -> np.ndarray:
    cols = []
    for tau in taus:
        a = pulse.shifted(tau, lo, hi)
        cols += [a.real, -a.imag]  # Re(A a) = Ar Re a - Ai Im a
    return np.stack(cols, axis=1)


def _solve(pulse, y, taus, lo, hi):
    B = _design(pulse, taus, lo, hi)
    G = B.T @ B  # normal equations (a tall, thin system: ~10x faster than lstsq's SVD) ...
    if np.linalg.cond(G) < 1e10:
        c = np.linalg.solve(G, B.T @ y)
    else:  # ... unless copies lie on top of each other: the minimum-norm amplitudes
        c, *_ = np.linalg.lstsq(B, y, rcond=None)
    return c, y - B @ c


def _fit_delays(pulse, y, taus0, lo, hi, bound: float):
    """Levenberg-Marquardt on the delays (amplitudes projected out), each kept within `bound`
    samples of where it started (and inside the window)."""
    from scipy.optimize import least_squares

    reach = (
        lo - pulse.centre - 0.5 * bound,
        hi - pulse.centre + 0.5 * bound,
    )  # delays that put the pulse in the window
    taus0 = np.clip(np.asarray(taus0, float), *reach)  # a start beyond it begins at its edge
    lower = np.maximum(taus0 - bound, reach[0])
    upper = np.minimum(taus0 + bound, reach[1])
    x0 = np.clip(taus0, lower + 1e-6, upper - 1e-6)
    sol = least_squares(
        lambda t: _solve(pulse, y, t, lo, hi)[1], x0, bounds=(lower, upper), x_scale=1.0, diff_step=1e-4
    )
    return sol.x


def _covariance(pulse, y, taus, c, lo, hi, inflation: float):
    """s^2 (J^T J)^-1 over (delays, Re A, Im A) per arrival, s^2 the residual variance x `inflation`."""
    K = len(taus)
    B = _design(pulse, taus, lo, hi)
    r = y - B @ c
    J = np.zeros((len(y), 3 * K))
    h = 1e-3
    for k in range(K):
        up, dn = np.array(taus, float), np.array(taus, float)
        up[k] += h
        dn[k] -= h
        J[:, 3 * k] = (_design(pulse, up, lo, hi) @ c - _design(pulse, dn, lo, hi) @ c) / (2 * h)
        J[:, 3 * k + 1] = B[:, 2 * k]
        J[:, 3 * k + 2] = B[:, 2 * k + 1]
    dof = max(
        len(y) - 3 * K * inflation, inflation
    )  # a band-limited residual: each parameter takes `inflation` samples
    s2 = float(r @ r) / dof * inflation
    # columns scaled to unit norm first: delays (samples) and amplitudes (the pulse's units) differ
    # in scale, and pinv's cut-off would otherwise depend on the pulse's amplitude
    norm = np.linalg.norm(J, axis=0)
    D = np.where(norm > 1e-12 * norm.max(initial=0.0), 1.0 / np.where(norm > 0, norm, 1.0), 1.0)  # a null column as is
    Js = J * D
    return s2 * (D[:, None] * np.linalg.pinv(Js.T @ Js) * D[None, :]), r


def _starts(pulse, r, taus, predicted, lo, hi, samples_per_period: float):
    """Starting delays for one more arrival: at each of the residual's three highest matched-filter
    envelope peaks (a period apart at least), with the others where they are and, again, with the
    predicted ones back at their predictions; and each copy split in two, half, one or two periods
    either side of where it sits (a single copy fitted across two arrivals sits between them, and
    the residual's peak then points at neither)."""
    full = np.zeros(pulse.n_fft)
    full[lo - pulse.offset : hi - pulse.offset] = r
    score = np.abs(np.fft.ifft(np.fft.fft(full) * np.conj(pulse.spec)))  # at each lag (delay), wrapped
    lags = np.fft.fftfreq(pulse.n_fft, 1.0 / pulse.n_fft)
    inside = (lags + pulse.centre >= lo) & (lags + pulse.centre < hi)
    score, lags = score[inside], lags[inside]
    peaks: list[float] = []
    for k in np.argsort(score)[::-1]:
        t = float(lags[k])
        if all(abs(t - p) >= samples_per_period for p in peaks):
            peaks.append(t)
        if len(peaks) == 3:
            break
    reset = list(predicted) + list(taus[len(predicted) :])
    for t in peaks:
        yield list(taus) + [t]
        yield reset + [t]
    for k, t in enumerate(taus):  # a copy split in two about where it sits
        for half in (0.5, 1.0, 2.0):
            split = list(taus)
            split[k] = t - half * samples_per_period
            yield split + [t + half * samples_per_period]


def _model(pulse, y, taus, c, lo, hi, inflation: float, n_eff: float, max_corr: float) -> dict:
    """One fitted order: its delays, amplitudes, covariance, residual, BIC and whether every pair of
    its delays is resolved (correlation below `max_corr`)."""
    cov, r = _covariance(pulse, y, taus, c, lo, hi, inflation)
    d = np.sqrt(np.maximum(np.diag(cov), 1e-300))
    corr = (cov / np.outer(d, d))[::3, ::3]
    off = np.abs(corr - np.diag(np.diag(corr)))
    return {
        "taus": np.asarray(taus, float),
        "c": c,
        "cov": cov,
        "r": r,
        "bic": _bic(float(r @ r), n_eff, len(taus)),
        "resolved": bool(off.max(initial=0.0) < max_corr),
    }


def _bic(rss: float, n_eff: float, k: int) -> float:
    return n_eff * math.log(max(rss, 1e-300) / n_eff) + 3 * k * math.log(n_eff)


def fit_arrivals(
    x,
    pulse: Pulse,
    predicted,
    lo: int,
    hi: int,
    *,
    samples_per_period: float,
    max_extra: int = 3,
    min_significance: float = 5.0,
    max_corr: float = 0.9,
    max_sigma_periods: float = 0.05,
) -> ArrivalFit:
    """Fit copies of `pulse` to `x[lo:hi]` (module docstring) from the `predicted` delays (samples,
    the first the surface's own first arrival), adding up to `max_extra` arrivals by the BIC.
    `samples_per_period`: the drive's period in samples (the delays' bounds and the flags use it)."""
    x = np.asarray(x, float)
    lo, hi = max(int(lo), 0), min(int(hi), len(x))
    if hi - lo < 8:
        raise ValueError(f"the window [{lo}, {hi}) holds fewer than 8 samples of the trace ({len(x)} samples)")
    predicted = [float(p) for p in np.atleast_1d(predicted)]
    if not predicted:
        raise ValueError("fit_arrivals needs at least one predicted delay (the surface's first arrival)")
    y = x[lo:hi]
    bound = 2.0 * samples_per_period  # a prediction moves at most two periods
    # the pulse on a grid round the window: shifts reach across it and the bounds beyond
    pulse = pulse.around(lo, hi, int(math.ceil((hi - lo) + abs(pulse.centre - 0.5 * (lo + hi)) + 2 * bound)))
    inflation = max(1.0, 1.0 / (2 * pulse.bandwidth))
    n_eff = (hi - lo) / inflation  # independent samples of a residual in the pulse's band
    k_max = min(len(predicted) + max_extra, int((n_eff - 1) // 3))  # no more parameters than data
    if k_max < len(predicted):
        raise ValueError(
            f"the window [{lo}, {hi}) holds {n_eff:.1f} independent samples of the pulse's band: too few for "
            f"{len(predicted)} arrivals (3 parameters each); widen the window"
        )
    first = predicted[0] + pulse.centre  # where the surface's own pulse sits (samples)
    if not lo - 0.5 * bound <= first <= hi + 0.5 * bound:
        raise ValueError(
            f"the predicted first arrival (pulse centre at sample {first:.1f}) lies outside the window [{lo}, {hi}) "
            f"of a {len(x)}-sample trace: the trace ends before the echo or the window misses it; "
            "record longer (a longer duration) or move the window onto the prediction"
        )
    taus = _fit_delays(pulse, y, predicted, lo, hi, bound)
    c, r = _solve(pulse, y, taus, lo, hi)
    # forward selection to k_max copies, then the order with the least BIC among those whose copies
    # the data resolve from each other (a step that does not pay can open the way to one that does:
    # two equal arrivals a period or two apart fitted by one copy leave a residual that one more copy
    # does not explain but two do)
    models = [_model(pulse, y, taus, c, lo, hi, inflation, n_eff, max_corr)]
    while len(taus) < k_max:
        best = None
        for start in _starts(pulse, r, taus, predicted, lo, hi, samples_per_period):
            trial = _fit_delays(pulse, y, start, lo, hi, bound)
            c2, r2 = _solve(pulse, y, trial, lo, hi)
            if best is None or float(r2 @ r2) < float(best[2] @ best[2]):
                best = (trial, c2, r2)
        assert best is not None
        taus, c, r = best
        models.append(_model(pulse, y, taus, c, lo, hi, inflation, n_eff, max_corr))
    chosen = 0
    for k in range(1, len(models)):
        m = models[k]
        if m["resolved"] and m["bic"] < models[chosen]["bic"] - BIC_MARGIN:
            chosen = k
    unresolved_better = any(
        not m["resolved"] and m["bic"] < models[chosen]["bic"] - BIC_MARGIN for m in models[chosen + 1 :]
    )
    taus, c, cov, r = (models[chosen][k] for k in ("taus", "c", "cov", "r"))
    origin: list[float | None] = list(predicted) + [None] * (len(taus) - len(predicted))
    arrivals = []
    for k, t in enumerate(taus):
        A = complex(c[2 * k], c[2 * k + 1])
        g = np.array([A.real, A.imag]) / max(abs(A), 1e-300)  # d|A| / d(Re A, Im A)
        var_a = float(g @ cov[3 * k + 1 : 3 * k + 3, 3 * k + 1 : 3 * k + 3] @ g)
        arrivals.append(
            Arrival(float(t), math.sqrt(max(cov[3 * k, 3 * k], 0.0)), A, math.sqrt(max(var_a, 0.0)), origin[k])
        )
    order = np.argsort([a.delay for a in arrivals])
    arrivals = [arrivals[i] for i in order]
    idx = [int(i) for i in order]
    sig = [k for k, a in enumerate(arrivals) if a.significance >= min_significance]
    first = sig[0] if sig else 0
    d = np.sqrt(np.maximum(np.diag(cov), 1e-300))
    corr = cov / np.outer(d, d)
    i0 = 3 * idx[first]
    first_corr = tuple(float(corr[i0, 3 * idx[k]]) for k in range(len(arrivals)) if k != first)
    why = []
    if not sig:
        why.append(f"no arrival is {min_significance:g} standard errors above zero")
    s_per = arrivals[first].sigma_delay / samples_per_period
    if s_per > max_sigma_periods:
        why.append(f"its standard error {s_per:.3f} periods exceeds {max_sigma_periods:g}")
    rms = float(np.sqrt(np.mean(y**2))) or 1.0
    return ArrivalFit(
        arrivals=tuple(arrivals),
        lo=lo,
        hi=hi,
        residual_rel=float(np.sqrt(np.mean(r**2))) / rms,
        first=first,
        first_corr=first_corr,
        unresolved_better=unresolved_better,
        separable=not why,
        why="; ".join(why) if why else "separable",
        samples_per_period=float(samples_per_period),
    )
