"""Datasheet records (data/datasheets, fit/datasheet.py): provenance required, nothing invented,
the equivalent baffled piston of a stated beam angle checked against the piston's own lobe."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.special import j1

from difflattice.fit.datasheet import REQUIRED_SOURCE, load_datasheet

RECORDS = sorted((Path(__file__).resolve().parents[2] / "data" / "datasheets").glob("*.toml"))


def test_shipped_records_carry_provenance():
    assert len(RECORDS) >= 3
    parts = set()
    for p in RECORDS:
        d = load_datasheet(p)
        parts.add(d.part)
        for key in REQUIRED_SOURCE:
            assert d.source[key].strip()
        assert d.half_angle_deg is not None or d.table is not None
    assert len(parts) == len(RECORDS)


@pytest.mark.parametrize("path", RECORDS, ids=lambda p: p.stem)
def test_equivalent_piston_reproduces_the_stated_beam(path):
    """The derived diameter's baffled piston, 20 log10 |2 J1(x)/x| at x = k a sin(t), is at the
    stated level at the stated half-angle (and above it inside)."""
    d = load_datasheet(path)
    if d.half_angle_deg is None:
        pytest.skip("no stated beam angle")
    dia = d.equivalent_piston_diameter_m(343.2)
    k = 2 * math.pi * d.frequency_hz / 343.2
    t = np.radians([0.5 * d.half_angle_deg, d.half_angle_deg])
    x = k * 0.5 * dia * np.sin(t)
    level = 20 * np.log10(np.abs(2 * j1(x) / x))
    assert level[1] == pytest.approx(d.beam_level_db, abs=1e-9)
    assert level[0] > d.beam_level_db


def test_a_record_without_a_table_refuses_to_make_a_lobe():
    d = load_datasheet(RECORDS[0])
    if d.table is None:
        with pytest.raises(ValueError, match="digitise"):
            d.lobe()


def test_bad_records_name_the_missing_key(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text('[source]\ndocument = "x"\n[device]\npart = "y"\nfrequency_hz = 40e3\n[beam]\nlevel_db = -6\n')
    with pytest.raises(ValueError, match="revision"):
        load_datasheet(p)
    p.write_text(
        '[source]\ndocument = "x"\nrevision = "1"\nurl = "u"\nlocation = "Fig. 3"\nquote = "q"\n'
        '[device]\npart = "y"\nfrequency_hz = 40e3\n[table]\nangle_deg = [0, 10, 20]\nlevel_db = [0, -1, -3]\n'
        'method = "m"\n'
    )
    with pytest.raises(ValueError, match="sigma_db"):
        load_datasheet(p)
    p.write_text(p.read_text() + "sigma_db = 0.5\n")
    lobe = load_datasheet(p).lobe()
    assert lobe.sigma_db[0] == 0.5 and lobe.frequency_hz == 40e3
