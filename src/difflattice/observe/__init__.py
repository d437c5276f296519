"""Observables computed from what the sensors recorded: the far field (Kirchhoff-Helmholtz), lobe
metrics, and the analytic reference solutions the tests and accuracy studies compare against."""
