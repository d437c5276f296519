"""Observables computed from what the sensors recorded: the far field (Kirchhoff-Helmholtz over
each lattice kind's surface, one protocol `farfield_base.FarFieldSurface`, chosen by the kind in
`surfaces`: 2-D in `farfield`, axisymmetric in `farfield_rz` with the rz scan-line sampler, 3-D in
`farfield3d`), lobe metrics, and the analytic reference solutions the tests and accuracy studies
compare against."""
