"""The house rules, checked: imports point down the layers (no cycle possible), the capture
package never imports JAX, and the public surface is what the docs say."""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "src" / "difflattice"

# bottom to top; a module may import from its own layer or any layer below it
LAYERS = {
    "air": 0,
    "config": 0,
    "transforms": 0,  # pure-Python parameter maps (logit, sigmoid)
    "lattice": 1,
    "solver": 2,
    "observe": 3,
    "scene": 4,
    "plots": 4.5,  # figures from arrays (matplotlib only); fit and design reports draw with it
    "fit": 5,
    "design": 5,
    "apps": 7,
    "cli": 8,
}
CAPTURE_MAY_IMPORT = {"air", "config", "capture"}


def _layer_of(parts: tuple[str, ...]) -> str:
    return parts[0] if parts else "__init__"


def _imports(path: Path) -> list[tuple[tuple[str, ...], int]]:
    """Every difflattice module a file imports (module level and inside functions), as parts
    relative to the package, with the line number."""
    rel = path.relative_to(PKG).with_suffix("").parts
    package = rel[:-1] if path.name != "__init__.py" else rel[:-1]
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - (node.level - 1)] if node.level > 1 else package
                mod = tuple(base) + (tuple(node.module.split(".")) if node.module else ())
                if not node.module:  # from . import x
                    for alias in node.names:
                        out.append((mod + (alias.name,), node.lineno))
                    continue
                out.append((mod, node.lineno))
            elif node.module and node.module.split(".")[0] == "difflattice":
                out.append((tuple(node.module.split(".")[1:]), node.lineno))
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "difflattice":
                    out.append((tuple(alias.name.split(".")[1:]), node.lineno))
    return out


def _modules():
    return sorted(p for p in PKG.rglob("*.py") if "__pycache__" not in p.parts)


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(PKG)))
def test_imports_point_down_the_layers(path):
    src = _layer_of(path.relative_to(PKG).with_suffix("").parts)
    if src == "__init__" or src == "__version__":
        return  # the top-level package only re-exports lazily
    for target, line in _imports(path):
        dst = _layer_of(target)
        if dst in ("__init__", "__version__", ""):
            continue
        if src == "capture":
            assert dst in CAPTURE_MAY_IMPORT, f"{path.name}:{line}: capture imports {'.'.join(target)} (JAX-free layer)"
            continue
        assert dst != "capture" or LAYERS[src] >= LAYERS["fit"], f"{path.name}:{line}: {src} imports capture"
        if dst == "capture":
            continue
        assert LAYERS[dst] <= LAYERS[src], (
            f"{path.relative_to(PKG)}:{line} imports difflattice.{'.'.join(target)}: layer {dst!r} "
            f"sits above {src!r} (see docs/architecture.md)"
        )


def test_star_import_and_public_surface():
    code = (
        "from difflattice import *\n"
        "import difflattice as dl\n"
        "names = [n for n in dl.__all__ if n != '__version__']\n"
        "missing = [n for n in names if n not in globals()]\n"
        "assert not missing, missing\n"
        "assert {'simulate', 'Grid', 'make_grid', 'Medium', 'Edges', 'Sensors', 'line_transducer', 'load_scene'} <= set(names)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]


def test_capture_and_air_import_without_jax():
    code = (
        "import sys\n"
        "import difflattice.air, difflattice.capture.host, difflattice.capture.files, difflattice.capture.emulator\n"
        "assert 'jax' not in sys.modules, sorted(m for m in sys.modules if m.startswith('jax'))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
