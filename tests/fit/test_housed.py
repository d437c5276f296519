"""The housed transducer model (fit/housed.py) and its fits (fit/ladder.py): geometry gradients
against central differences, recovery of a recessed piston from an independent finer lattice run,
the family ladder's choice, bounds and errors."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.fit.data import LobeData
from difflattice.fit.housed import HousedForward, HousedSpec, Housing, level_db, ring_volume_fractions, row_fractions
from difflattice.fit.ladder import COND_MAX, choose_family, family_ladder

F_HZ = 40e3


def test_cut_cell_fractions_are_exact_volumes():
    """Ring-volume and row fractions of an annulus [r1, r2] x [z1, z2] sum to its exact volume
    (pi (r2^2 - r1^2)(z2 - z1) in cells^3, a ring's volume being pi (2j + 1))."""
    r1, r2, z1, z2 = 2.3, 6.7, 1.25, 4.6
    fr = np.asarray(ring_volume_fractions(r1, r2, 10, np.float64))
    fz = np.asarray(row_fractions(z1, z2, 8, np.float64))
    vol = np.sum(fr * np.pi * (2 * np.arange(10) + 1)) * np.sum(fz)
    assert vol == pytest.approx(np.pi * (r2**2 - r1**2) * (z2 - z1), rel=1e-12)


def test_bad_geometry_is_refused_with_the_fix():
    h = Housing(outer_diameter_m=16e-3, length_m=12e-3)
    with pytest.raises(ValueError, match="nothing is larger than the can"):
        HousedSpec(housing=h, frequency_hz=F_HZ, diaphragm_m=20e-3)
    with pytest.raises(ValueError, match="raise cells_per_wavelength"):
        HousedSpec(housing=h, frequency_hz=F_HZ, cells_per_wavelength=8, family="opening")
    with pytest.raises(ValueError, match="outer_diameter_m"):
        Housing(outer_diameter_m=-1.0, length_m=12e-3)
    with pytest.raises(ValueError, match="family"):
        HousedSpec(housing=h, frequency_hz=F_HZ, family="horn")
    with pytest.raises(ValueError, match="back = 'closed'"):
        Housing(outer_diameter_m=16e-3, length_m=12e-3, front="flange", back="open")
    with pytest.raises(ValueError, match="front"):
        Housing(outer_diameter_m=16e-3, length_m=12e-3, front="wall")  # type: ignore[arg-type]


@pytest.mark.parametrize("front", ["free", "flange"])
def test_lobe_gradient_in_recess_and_opening_matches_central_differences(front):
    """d(lobe dB)/d(recess, opening, diameter) by forward-mode through the lattice run equals
    central differences of the run itself, to 1e-4 relative (float64). The step (1e-4 in the
    logit, ~1e-4 mm) keeps every body's edge inside one cell, where the cut-cell fractions are
    smooth; the O(h^2) truncation is ~1e-8 relative. A flanged can (its depth interpolated between
    whole rows, `HousedForward`) also with the wavefront's phase on a scan line 10 mm in front of
    the face (deg)."""
    h = Housing(outer_diameter_m=16e-3, length_m=10e-3, plate_m=1.8e-3, front=front)
    spec = HousedSpec(housing=h, frequency_hz=F_HZ, cells_per_wavelength=10, family="opening")
    ang = np.array([0.0, 20.0, 40.0, 60.0])
    if front == "free":
        fw = HousedForward(spec, ang)
        out = fw.lobe_db
    else:
        fw = HousedForward(spec, ang, wave_x_m=np.array([0.0, 4e-3, 8e-3]), wave_z_m=10e-3)

        def out(q):
            far, near = fw.fields(q)
            return jnp.concatenate([level_db(far, q), jnp.degrees(jnp.angle(near))])

    p = spec.truth_params(diaphragm_m=9.1e-3, recess_m=3.3e-3, opening_m=11.3e-3)
    f = jax.jit(out)
    jac = jax.jit(jax.jacfwd(out))(p)
    e = 1e-4
    for key in ("recess", "opening", "diam"):
        up = dataclasses.replace(p, **{key: getattr(p, key) + e})
        dn = dataclasses.replace(p, **{key: getattr(p, key) - e})
        fd = (np.asarray(f(up)) - np.asarray(f(dn))) / (2 * e)
        g = np.asarray(getattr(jac, key))
        assert np.max(np.abs(g)) > 0.05, key  # the lobe does depend on it
        np.testing.assert_allclose(g, fd, rtol=1e-4, atol=1e-4 * np.max(np.abs(fd)), err_msg=key)


def _reference_lobe(h: Housing, ang, diaphragm_m: float, recess_m: float) -> np.ndarray:
    """The independent reference: the recessed piston on a lattice twice as fine (24 cells per
    wavelength) with the other spatial stencil ("isotropic"), whose cut cells fall elsewhere."""
    ref = HousedSpec(housing=h, frequency_hz=F_HZ, cells_per_wavelength=24, family="recessed", stencil="isotropic")
    y = np.asarray(
        jax.jit(HousedForward(ref, ang).lobe_db)(ref.truth_params(diaphragm_m=diaphragm_m, recess_m=recess_m))
    )
    return y - y[0]


def test_recessed_piston_recovered_and_chosen_by_the_ladder():
    """Synthetic datasheet: a 9 mm piston 3 mm deep in a 16 x 12 mm can (wall 0.5 mm), its lobe
    by the independent reference (`_reference_lobe`), sigma 0.2 dB (a datasheet's digitising
    sigma), no noise added. Fitted at 12 cells per wavelength with the resolution term from a
    refit at 16 (`resolution_cpw`): the ladder prefers "recessed" to "flat" by BIC, the free
    profile is flagged ill-conditioned, and diameter and depth are recovered within 2 quoted
    sigmas (statistical and resolution terms in quadrature)."""
    h = Housing(outer_diameter_m=16e-3, length_m=12e-3)
    ang = np.arange(0.0, 81.0, 5.0)
    y = _reference_lobe(h, ang, 9e-3, 3e-3)
    lobe = LobeData(
        angle_deg=ang,
        level_db=y,
        sigma_db=np.full(len(ang), 0.2),
        range_m=1.0,
        frequency_hz=F_HZ,
        cycles=0.0,
        temperature_c=20.0,
        source="reference",
    )
    spec = HousedSpec(housing=h, frequency_hz=F_HZ, cells_per_wavelength=12)
    lad = family_ladder(spec, lobe, families=("flat", "recessed", "profile"), starts=1, resolution_cpw=16)
    print(lad.markdown())
    rec = lad.fits["recessed"]
    assert lad.chosen == "recessed", lad.markdown()
    assert rec.converged and not rec.ill_conditioned and not rec.at_bound
    assert lad.fits["profile"].ill_conditioned, lad.markdown()
    assert lad.fits["recessed"].bic < lad.fits["flat"].bic - 2
    for key, truth in (("diaphragm_mm", 9.0), ("recess_mm", 3.0)):
        err = rec.errors[key]
        assert 0 < err < 1.0, (key, err)
        assert abs(rec.physical[key] - truth) < 2 * err, (key, rec.physical[key], err)


def test_choose_family_prefers_simpler_and_rejects_ill_conditioned():
    class F:
        def __init__(self, chi2, k, cond):
            self.chi2, self.k, self.n, self.condition, self.converged = chi2, k, 30, cond, True

        bic = property(lambda s: s.chi2 + s.k * math.log(s.n))
        ill_conditioned = property(lambda s: not s.condition <= COND_MAX)

    fits = {"flat": F(40.0, 2, 1.0), "recessed": F(39.0, 3, 10.0), "profile": F(1.0, 5, 1e13)}
    chosen, reason = choose_family(fits)
    assert chosen == "flat"  # recessed's BIC is higher: 1 chi2 does not pay for a parameter
    assert "ill-conditioning" in reason
    fits["recessed"] = F(20.0, 3, 10.0)
    assert choose_family(fits)[0] == "recessed"


def test_open_back_radiates_antisymmetrically():
    """An open-back can whose diaphragm plate sits mid-tube is antisymmetric under z -> -z about
    the plate (the rear face moves the air the other way): the far field has an exact null at
    90 deg and the same level at 180 deg as on axis, to round-off. A closed back has neither."""
    dx = 343.2 / (F_HZ * 12.0)
    d = 3e-3
    levels = {}
    for back in ("open", "closed"):
        h = Housing(outer_diameter_m=16e-3, length_m=2 * d + dx, back=back)
        spec = HousedSpec(housing=h, frequency_hz=F_HZ, cells_per_wavelength=12.0, family="recessed")
        fw = HousedForward(spec, np.array([0.0, 90.0, 180.0]))
        f = np.abs(np.asarray(jax.jit(fw.far_field)(spec.truth_params(diaphragm_m=9e-3, recess_m=d))))
        levels[back] = f / f[0]
    assert levels["open"][1] < 1e-9
    assert levels["open"][2] == pytest.approx(1.0, rel=1e-9)
    assert levels["closed"][1] > 1e-2 and levels["closed"][2] < 0.5


def test_fixed_geometry_is_held_and_reported():
    h = Housing(outer_diameter_m=16e-3, length_m=10e-3, plate_m=1.5e-3)
    spec = HousedSpec(
        housing=h, frequency_hz=F_HZ, cells_per_wavelength=12, family="opening", opening_m=8e-3, fixed=("opening",)
    )
    p = spec.init_params()
    assert not p.has("opening") and {"diam", "recess", "gain_db"} <= set(p.names())
    assert float(spec.physical(p)["opening_m"]) == pytest.approx(8e-3)
    with pytest.raises(ValueError, match="needs its value"):
        HousedSpec(housing=h, frequency_hz=F_HZ, cells_per_wavelength=12, family="opening", fixed=("opening",))
    with pytest.raises(ValueError, match="not a geometry parameter"):
        HousedSpec(housing=h, frequency_hz=F_HZ, cells_per_wavelength=12, fixed=("gain",))


def test_near_field_tends_to_the_far_field():
    """The scan-line prediction (`near_field`) at range R on the axis is F(0) exp(ikR) / R up to
    O(L / R) (L ~ 30 mm, the sources' extent about the origin): at R = 100 m, |p| R / |F| = 1
    within 1e-3, and arg p - arg F = k R within 0.01 rad (the O(k L^2 / R) curvature term is
    3e-3 rad). The spec's recess is 1 mm and the parameters' 3 mm: the line lies 100 m in front of
    the face the parameters put (0.01 rad is 0.014 mm of its distance; a line left at the spec's
    face would be 2 mm, 1.5 rad, off). Too near the can is refused with the distance needed."""
    h = Housing(outer_diameter_m=16e-3, length_m=12e-3)
    spec = HousedSpec(housing=h, frequency_hz=F_HZ, cells_per_wavelength=10, family="recessed", recess_m=1e-3)
    z = 100.0
    fw = HousedForward(spec, np.array([0.0]), wave_x_m=np.array([0.0]), wave_z_m=z)
    p = spec.truth_params(diaphragm_m=9e-3, recess_m=3e-3)
    r_m = fw.layout.diaphragm_row * fw.layout.dx_m + 3e-3 + z  # from the lattice origin, the far field's
    far, near = (complex(np.asarray(v)[0]) for v in jax.jit(fw.fields)(p))
    r_cells = r_m / fw.layout.dx_m  # `far_field_rz` is R p in Pa x cells
    assert abs(near) * r_cells / abs(far) == pytest.approx(1.0, abs=1e-3)
    dphi = np.angle(near / far * np.exp(-2j * np.pi * F_HZ * r_m / spec.c_m_s))
    assert abs(dphi) < 0.01, dphi
    with pytest.raises(ValueError, match="give wave_z_m >"):
        HousedForward(spec, np.array([0.0]), wave_x_m=np.array([0.0]), wave_z_m=1e-3)
