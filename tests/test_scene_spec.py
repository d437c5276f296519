"""The typed scene spec: every shipped scene builds the arrays the dict-shaped scene code built
(fingerprints written by that code, tests/scene/builds.json), and the tagged unions of
transducers and objects refuse a key of another type or shape, or an unknown one, naming the
place and the fix."""

import json
import math
import sys
import warnings
from dataclasses import FrozenInstanceError
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent / "scene"))
from fingerprint import build, fingerprint, scene_names  # noqa: E402

from difflattice.scene import (  # noqa: E402
    DiscTransducer,
    LineTransducer,
    SceneError,
    load_scene,
    parse_scene,
)
from difflattice.scene.schema import BoxObject, UnionObject  # noqa: E402

PINNED = json.loads((Path(__file__).resolve().parent / "scene" / "builds.json").read_text())

REL = 1e-6
"""Relative tolerance of a float array's sums: far below any moved cell or changed weight, far
above another CPU's last-bit differences (see tests/scene/fingerprint.py)."""


def _same(a, b, where: str) -> None:
    if isinstance(a, dict) and "sums" in a:
        assert a["shape"] == b["shape"], where
        for x, y in zip(a["sums"], b["sums"]):
            assert math.isclose(x, y, rel_tol=REL, abs_tol=1e-12 * max(1.0, abs(a["sums"][1]) ** 0.5)), where
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for k in a:
            _same(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{where}[{i}]")
    elif isinstance(a, float) and isinstance(b, float):
        assert math.isclose(a, b, rel_tol=1e-12), where
    else:
        assert a == b, where


def test_every_shipped_scene_is_fingerprinted():
    assert set(PINNED) == set(scene_names())


@pytest.mark.parametrize("name", scene_names())
def test_scene_builds_the_arrays_of_the_dict_shaped_code(name):
    """Grid, medium maps, sources (cells, weights, lags, signal), sensors, edges, far-field
    surface, run length and images of each scene at a cheap resolution: as pinned by the code
    before the typed spec (c9ce57d)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        got = fingerprint(build(name))
    _same(PINNED[name], got, name)


# ------------------------------------------------------------------------------------------
# the tagged unions

LINE = {
    "grid": {"frequency_hz": 40e3, "size_m": [0.05, 0.05]},
    "transducers": [{"centre_m": [0.01, 0.02]}],
    "run": {"n_steps": 5},
}


def _with(section: str, item: dict) -> dict:
    return LINE | {section: [item]}


def test_tables_become_the_class_their_tag_names():
    s = parse_scene(LINE | {"objects": [{"shape": "box", "lo_m": [0, 0], "hi_m": [0.01, 0.01]}]}, "ok")
    assert isinstance(s.transducers[0], LineTransducer) and s.transducers[0].type == "line"
    assert isinstance(s.objects[0], BoxObject) and s.objects[0].material_name == "rigid"
    d = parse_scene(
        {
            "grid": {"kind": "3d", "frequency_hz": 40e3, "size_m": [0.05] * 3},
            "transducers": [{"type": "disc", "centre_m": [0.01, 0.02, 0.02], "diameter_m": 0.01}],
            "objects": [
                {
                    "shape": "union",
                    "parts": [{"shape": "sphere", "centre_m": [0.03] * 3, "radius_m": 0.005}],
                    "cut": {"shape": "halfspace", "point_m": [0.03] * 3, "normal": [1, 0, 0]},
                }
            ],
        },
        "ok3",
    )
    assert isinstance(d.transducers[0], DiscTransducer)
    u = d.objects[0]
    assert isinstance(u, UnionObject) and u.parts[0].shape == "sphere" and u.cut.shape == "halfspace"
    with pytest.raises(FrozenInstanceError):
        s.grid.frequency_hz = 1.0  # type: ignore[misc]


@pytest.mark.parametrize(
    "section, item, match",
    [
        (  # a disc's key on a line
            "transducers",
            {"centre_m": [0.01, 0.02], "baffle": "rigid"},
            r"bad: \[transducers\[0\]\.baffle\] is a key of disc transducers, not line ones: remove it, or set "
            r'type = "disc"',
        ),
        (  # a line's key on a disc
            "transducers",
            {"type": "disc", "centre_m": [0.01, 0], "direction_deg": 90.0},
            r"\[transducers\[0\]\.direction_deg\] is a key of line transducers, not disc ones: remove it, or set "
            r'type = "line"',
        ),
        (  # an unknown type, with the close match and the known ones
            "transducers",
            {"type": "disk", "centre_m": [0.01, 0.02]},
            r"\[transducers\[0\]\.type\] = \"disk\" is not a known transducer type \(did you mean 'disc'\?\); "
            r"allowed: 'line', 'disc'",
        ),
        (  # a key of several other shapes names them all
            "objects",
            {"shape": "box", "lo_m": [0, 0], "hi_m": [0.01, 0.01], "radius_m": 0.01},
            r"\[objects\[0\]\.radius_m\] is a key of circle, sphere and cylinder objects, not box ones: remove it, "
            r'or set shape = "circle"',
        ),
        (  # a key of no shape at all: the close match and this shape's keys
            "objects",
            {"shape": "circle", "centre_m": [0.02, 0.02], "radius": 0.01},
            r"\[objects\[0\]\.radius\] unknown key \(did you mean 'radius_m'\?\); allowed: shape, material",
        ),
        (  # a shape's own required key, inside a cut
            "objects",
            {"shape": "box", "lo_m": [0, 0], "hi_m": [0.01, 0.01], "cut": {"shape": "circle", "centre_m": [0, 0]}},
            r"\[objects\[0\]\.cut\.radius_m\] is required: radius; allowed: > 0 m; fix: give it",
        ),
        ("objects", {"lo_m": [0, 0]}, r"\[objects\[0\]\.shape\] is required: the object's shape; allowed: 'segment'"),
    ],
)
def test_union_errors_name_the_place_and_the_fix(section, item, match):
    with pytest.raises(SceneError, match=match):
        parse_scene(_with(section, item), "bad")


def test_kind_checks_stay_in_the_build():
    """Keys legal for a type but not for the grid's kind are refused when the scene is built."""
    rz = {
        "grid": {"kind": "rz", "frequency_hz": 40e3, "size_m": [0.05, 0.03]},
        "edges": {"z_lo": "rigid"},
        "run": {"n_steps": 5},
    }
    s = parse_scene(rz | {"transducers": [{"type": "disc", "centre_m": [0, 0], "diameter_m": 0.01, "receive": True}]})
    with pytest.raises(SceneError, match=r"transducers\[0\]\.receive\] is implemented for 3d grids"):
        s.build()
    s = parse_scene(
        rz | {"transducers": [{"type": "disc", "centre_m": [0, 0], "diameter_m": 0.01, "injection": "hard"}]}
    )
    with pytest.raises(SceneError, match=r'injection\] = "hard" is not an rz disc: leave injection out'):
        s.build()
    box3 = {"shape": "box", "centre_m": [0.01, 0.01], "size_m": [0.01, 0.01]}
    with pytest.raises(SceneError, match=r"objects\[0\]\.centre_m\] is for 3d boxes"):
        parse_scene(_with("objects", box3)).build()


def test_at_resolution_and_as_dict_work_on_the_typed_spec():
    """`at_resolution` derives a new frozen scene (the original untouched); `as_dict` gives tables
    that parse back to the same scene."""
    f = Path(__file__).resolve().parents[1] / "src" / "difflattice" / "scenes" / "fig02_polaroid.toml"
    scene = load_scene(f)
    coarse = scene.at_resolution(10.0)
    assert coarse.grid.cells_per_wavelength == 10.0 and scene.grid.cells_per_wavelength == 20.0
    assert coarse.transducers[0].n_cells == round(scene.transducers[0].n_cells / 2)
    for s in (scene, coarse, load_scene(f.with_name("corner3d.toml"))):
        assert parse_scene(s.as_dict(), s.path) == s
