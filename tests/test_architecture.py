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


def _imports(path: Path, *, at_run_time: bool = False) -> list[tuple[tuple[str, ...], int]]:
    """Every difflattice module a file imports (module level and inside functions), as parts
    relative to the package, with the line number; `at_run_time`: leave out the imports under
    `if TYPE_CHECKING:` (for type checkers only)."""
    rel = path.relative_to(PKG).with_suffix("").parts
    package = rel[:-1] if path.name != "__init__.py" else rel[:-1]
    out = []
    tree = ast.parse(path.read_text())
    typing_only: set[int] = set()
    if at_run_time:
        for node in ast.walk(tree):
            if isinstance(node, ast.If) and getattr(node.test, "id", getattr(node.test, "attr", "")) == "TYPE_CHECKING":
                typing_only |= {id(n) for b in node.body for n in ast.walk(b)}
    for node in ast.walk(tree):
        if id(node) in typing_only:
            continue
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


def _module_of(parts: tuple[str, ...]) -> tuple[str, ...] | None:
    """The module (file) that importing `parts` runs: a module file, a package's __init__, or, for
    `from pkg import name` where name is no module, the package."""
    while parts:
        if (PKG.joinpath(*parts).with_suffix(".py")).is_file():
            return parts
        if (PKG.joinpath(*parts) / "__init__.py").is_file():
            return parts + ("__init__",)
        parts = parts[:-1]
    return None


def test_no_import_circles_even_through_function_level_imports():
    """The graph of every import the package runs (module level and inside functions, each also
    running the __init__ of the packages it passes through, except the importer's own; not those
    under `if TYPE_CHECKING:`) has no cycle. The top-level package's __init__ only re-exports lazily and is left out."""
    graph: dict[tuple[str, ...], set[tuple[str, ...]]] = {}
    for path in _modules():
        src = path.relative_to(PKG).with_suffix("").parts
        if src == ("__init__",):
            continue
        own = {src[:i] for i in range(len(src))}
        edges = graph.setdefault(src, set())
        for target, _ in _imports(path, at_run_time=True):
            dst = _module_of(target)
            if dst is None or dst == src or dst == ("__init__",):
                continue
            edges.add(dst)
            for i in range(1, len(dst) - 1):  # packages on the way run their __init__ first
                pkg = dst[:i]
                if pkg not in own and (PKG.joinpath(*pkg) / "__init__.py").is_file():
                    edges.add(pkg + ("__init__",))
    cycles, state = [], {}

    def visit(node, stack):
        state[node] = "open"
        stack.append(node)
        for nxt in sorted(graph.get(node, set())):
            if state.get(nxt) == "open":
                cycles.append(" -> ".join(".".join(p) for p in stack[stack.index(nxt) :] + [nxt]))
            elif nxt not in state:
                visit(nxt, stack)
        stack.pop()
        state[node] = "done"

    for node in sorted(graph):
        if node not in state:
            visit(node, [])
    assert not cycles, "\n".join(cycles)
