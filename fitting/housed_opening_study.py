"""What does a far-field lobe say about a diaphragm behind a front plate? A SYNTHETIC study.

A 12 mm diaphragm 2.5 mm behind a 1.5 mm front plate with an 8 mm opening, in a 16 x 10 mm closed
can, 40 kHz: its far-field lobe by the rz lattice at 32 cells per wavelength (isotropic stencil),
0-80 deg in 5 deg steps, rounded to 0.1 dB, sigma 0.2 dB; then the family ladder (fit.ladder) at
16 cells per wavelength with the resolution term from 20. Prints the ladder's table.

    .venv/bin/python fitting/housed_opening_study.py
"""

from __future__ import annotations

import numpy as np


def run(quick: bool = False) -> str:
    import jax

    jax.config.update("jax_enable_x64", True)
    from difflattice.fit.data import LobeData
    from difflattice.fit.housed import HousedForward, HousedSpec, Housing
    from difflattice.fit.ladder import family_ladder

    h = Housing(outer_diameter_m=16e-3, length_m=10e-3, plate_m=1.5e-3)
    ang = np.arange(0.0, 81.0, 5.0)
    ref = HousedSpec(
        housing=h, frequency_hz=40e3, cells_per_wavelength=16 if quick else 32, family="opening", stencil="isotropic"
    )
    p = ref.truth_params(diaphragm_m=12e-3, recess_m=2.5e-3, opening_m=8e-3)
    y = np.asarray(jax.jit(HousedForward(ref, ang).lobe_db)(p))
    y = np.round(y - y[0], 1)
    lobe = LobeData(
        angle_deg=ang,
        level_db=y,
        sigma_db=np.full(len(ang), 0.2),
        range_m=1.0,
        frequency_hz=40e3,
        cycles=0.0,
        temperature_c=20.0,
        source="housed_opening_study (synthetic)",
    )
    spec = HousedSpec(housing=h, frequency_hz=40e3, cells_per_wavelength=12 if quick else 16)
    lad = family_ladder(
        spec,
        lobe,
        families=("flat", "opening") if quick else ("flat", "recessed", "opening", "profile"),
        starts=1 if quick else 3,
        resolution_cpw=None if quick else 20,
    )
    return lad.markdown()


if __name__ == "__main__":
    print(run())
