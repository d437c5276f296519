"""What every fit report must satisfy (issue 27): no NaN, no limit outside the physical range
(negative, or below an atom's size, ~1e-7 mm), no zero error for a fitted quantity (+-0.000),
and every ring or cell of the model in the per-cell tables."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

ATOM_MM = 1e-7


def assert_sane_report(out_dir: Path) -> dict:
    text = (Path(out_dir) / "report.json").read_text()
    assert "NaN" not in text and "Infinity" not in text, "a non-finite number in report.json"
    js = json.loads(text)
    md = (Path(out_dir) / "report.md").read_text()
    assert not re.search(r"\bnan\b", md, re.IGNORECASE), "NaN in report.md"
    assert not re.search(r"±\s*[-+]?0\.0*(?![0-9])", md), "a ±0.000 error in report.md"
    b = js["budget"]
    for e in b["scalars"] + b["weights"] + b["lags"]:
        for k in ("value", "stat", "total"):
            assert e[k] is not None and math.isfinite(e[k]), (e["name"], k, e[k])
        if e["status"] == "at_bound":
            lim = e["limit_value"]
            assert lim is not None and math.isfinite(lim), e
            if e["name"] == "diameter_mm":
                assert ATOM_MM < lim <= js["fit"]["model"]["n_cells"] * js["fit"]["model"]["dx_m"] * 2e3, e
        if e["status"] == "determined":
            assert e["total"] > 1e-12 * max(abs(e["value"]), 1.0), e  # a fitted quantity has an error
    n = js["fit"]["model"]["n_cells"]
    for key in ("weights", "lags"):
        ys = [e["y_mm"] for e in b[key]]
        if ys:  # every ring (disc), or every cell at y >= 0 plus the unpaired ones (mirror pairs: once)
            expect = n if js["fit"]["model"]["family"] == "disc" or not b["aliases"] else (n + 1) // 2
            assert len(ys) >= expect, (key, len(ys), n)
            rows = [ln for ln in md.splitlines() if re.match(r"^\| [+-]\d+\.\d\d \|", ln)]
            assert len(rows) >= len(b["weights"]) + len(b["lags"]), (len(rows), key)  # none left out of the tables
    return js
