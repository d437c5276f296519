"""Regenerate the key tables of docs/scene-files.md from the scene schema.

Usage (from the repository root):

    .venv/bin/python docs/gen_scene_files.py            # rewrites the generated part in place
    .venv/bin/python docs/gen_scene_files.py --check    # exit 1 if docs/scene-files.md is out of date

The part between the markers ``<!-- BEGIN GENERATED: schema -->`` and ``<!-- END GENERATED:
schema -->`` is `difflattice.scene.schema_markdown()` (every section and key, from the typed
declarations in `difflattice/scene/schema.py`: one table per section, and for the tagged unions
`[[transducers]]` and `[[objects]]` one table of the keys they all have followed by one table per
transducer type and object shape with its own keys) followed by the materials table
(`difflattice.lattice.medium.MATERIALS`); the rest of the page is written by hand.
"""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
PAGE = HERE / "scene-files.md"
BEGIN = "<!-- BEGIN GENERATED: schema -->"
END = "<!-- END GENERATED: schema -->"


def generated() -> str:
    sys.path.insert(0, str(ROOT / "src"))
    from difflattice.lattice.medium import MATERIALS
    from difflattice.scene import schema_markdown

    lines = [
        schema_markdown().rstrip(),
        "",
        "### Materials",
        "",
        "| name | kind | speed (m/s) | density (kg/m³) |",
        "|---|---|---|---|",
    ]
    for name, m in MATERIALS.items():
        if m.kind == "fluid":
            lines.append(f"| `{name}` | {m.kind} | {m.speed_m_s:.0f} | {m.density_kg_m3:.4g} |")
        else:
            lines.append(f"| `{name}` | {m.kind} | — | — |")
    return "\n".join(lines) + "\n"


def render(page: str) -> str:
    if BEGIN not in page or END not in page:
        raise SystemExit(f"{PAGE}: markers {BEGIN!r} and {END!r} not found")
    head, rest = page.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    return f"{head}{BEGIN}\n{generated()}{END}{tail}"


def main(argv: list[str]) -> int:
    page = PAGE.read_text()
    new = render(page)
    if "--check" in argv:
        if new != page:
            print(f"{PAGE} is out of date: run python docs/gen_scene_files.py", file=sys.stderr)
            return 1
        return 0
    PAGE.write_text(new)
    print(f"wrote {PAGE}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
