"""Fitting transducer models (per-cell weights, lags, active diameter) to measured beams.

Data flow: captures (`data.py`) -> free-field transfer of one source cell computed once by the
simulator (`transfer.py`) -> model observables, linear in the complex cell amplitudes
w_k exp(i omega tau_k) (`model.py`) -> optimistix least squares (robust losses, a returned
convergence trace, the statistical covariance; `solve.py`) -> error budget (statistical +
resolution + model, identifiability, bounds; `uncertainty.py` over `quantities.py`,
`families.py`, `identify.py`, `estimates.py`) -> report (`report.py`);
`config.py` runs a fit file.
"""
