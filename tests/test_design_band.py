"""Broadband design: the burst's band, the band problem's beam against the carrier's, and the
comparison's verdict."""

import numpy as np
import pytest

from difflattice.design.band import verdict
from difflattice.design.presets import FIG09_CONE, HORN_LIMITS, PAPER_FACE_M
from difflattice.design.problem import band_frequencies, horn_design


def test_burst_band_spans_the_hann_bursts_6db_width():
    """A Hann-windowed N-cycle burst of duration N / f0 has a -6 dB spectral width of 2.00 bins
    (Harris 1978, Table 1; one bin = f0 / N): the band's ends are f0 -+ f0 / N, within 1 % of a
    bin; the weights are symmetric about the carrier (|S(f0 + d)| = |S(f0 - d)| up to the tiny
    negative-frequency image) and sum to 1."""
    f0, n = 50e3, 5.0
    freqs, w = band_frequencies("burst", f0, n)
    assert freqs[0] == pytest.approx(f0 - f0 / n, abs=0.01 * f0 / n)
    assert freqs[-1] == pytest.approx(f0 + f0 / n, abs=0.01 * f0 / n)
    assert sum(w) == pytest.approx(1.0)
    assert w[0] == pytest.approx(w[-1], rel=1e-3) and max(w) == w[len(w) // 2]
    assert band_frequencies([40e3, 60e3], f0, n) == ((40e3, 60e3), (0.5, 0.5))
    with pytest.raises(ValueError, match="band"):
        band_frequencies("chirp", f0, n)
    with pytest.raises(ValueError, match="positive frequencies"):
        band_frequencies([-1.0], f0, n)


def test_a_band_of_the_carrier_alone_is_the_carriers_beam():
    """The band problem's DFT of the recorded contour pressures at the carrier is the same sum
    the running phasors accumulate, so its energy pattern is |carrier pattern| to round-off."""
    kw = dict(limits=HORN_LIMITS, face_m=PAPER_FACE_M, cells_per_wavelength=4.0, wall="soft", reference=False)
    carrier = horn_design(**kw)
    band = horn_design(**kw, band=[carrier.grid.frequency_hz])
    a = np.abs(np.asarray(carrier.pattern(FIG09_CONE)))
    b = np.asarray(band.pattern(FIG09_CONE))
    assert np.max(np.abs(a - b)) <= 1e-10 * a.max()


def test_verdict_names_the_narrower_design_over_the_band():
    row = lambda ws: [{"beam_width_deg": x, "on_axis_db": 0.0} for x in ws]
    t = {
        "frequencies_hz": [40e3, 50e3, 60e3],
        "a": {"per_frequency": row([12.0, 9.0, 7.0]), "energy": {"beam_width_deg": 9.4}},
        "b": {"per_frequency": row([11.0, 9.5, 7.5]), "energy": {"beam_width_deg": 9.2}},
    }
    v = verdict(t, "a", "b")
    assert "the b design is narrower" in v and "a narrower at 2 of 3" in v and "b at 1" in v


def test_resolution_auto_is_the_coarsest_under_the_trust_threshold():
    """`--resolution auto`: the chosen resolution's expected phase error is under the threshold
    and one cell per wavelength coarser is not; a ceiling below it is used and said to be not
    enough. (Problems are built without simulating: the estimate needs only the grid and run.)"""
    from difflattice.design.study import TRUST_PHASE_ERROR_PERIODS, choose_resolution, trust_estimate

    def build(n):
        return horn_design(limits=HORN_LIMITS, face_m=PAPER_FACE_M, cells_per_wavelength=n, reference=False)

    cpw, t, note = choose_resolution(build, 8.0, 40.0)
    assert (
        t["expected_phase_error_periods"]
        <= TRUST_PHASE_ERROR_PERIODS
        < trust_estimate(build(cpw - 1))["expected_phase_error_periods"]
    )
    assert "the coarsest under the trust threshold" in note
    cpw, t, note = choose_resolution(build, 8.0, 10.0)
    assert cpw == 10.0 and not t["trustworthy"] and "is above the trust threshold" in note
