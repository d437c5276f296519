"""Observables computed from what the sensors recorded: the far field (Kirchhoff-Helmholtz; 2-D in
`farfield`, axisymmetric in `farfield_rz` with the rz scan-line sampler), lobe metrics, and the
analytic reference solutions the tests and accuracy studies compare against."""
