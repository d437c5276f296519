"""Regenerate the configuration tables of docs/fitting.md and docs/capture.md from the typed
declarations (`difflattice.config`): the fit config's sections (`difflattice.fit.config`), the
capture file's header keys and measurement metadata (`difflattice.capture.files`) and the rig
emulator's options (`difflattice.capture.emulator`).

Usage (from the repository root):

    .venv/bin/python docs/gen_config_tables.py            # rewrites the generated parts in place
    .venv/bin/python docs/gen_config_tables.py --check    # exit 1 if a page is out of date

Each generated part lies between ``<!-- BEGIN GENERATED: <name> -->`` and
``<!-- END GENERATED: <name> -->``; the rest of the pages is written by hand.
"""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


def _parts() -> dict[Path, dict[str, str]]:
    if str(ROOT / "src") not in sys.path:
        sys.path.insert(0, str(ROOT / "src"))
    from difflattice.capture.emulator import Faults, Noise, RigConfig
    from difflattice.capture.files import Measurement, ScanHeader
    from difflattice.config import markdown_table
    from difflattice.fit.config import config_markdown
    from difflattice.fit.housed_config import housed_config_markdown

    return {
        HERE / "fitting.md": {"fit-config": config_markdown()},
        HERE / "housed.md": {"housed-config": housed_config_markdown()},
        HERE / "capture.md": {
            "capture-header": markdown_table(ScanHeader, heading="Written by the capture", level=4)
            + "\n"
            + markdown_table(Measurement, heading="Measurement metadata (given by the operator)", level=4),
            "emulator-options": "\n".join(
                markdown_table(c, heading=f"`{c.SECTION}` ({c.__name__})", level=4) for c in (RigConfig, Noise, Faults)
            ),
        },
    }


def render(page: str, parts: dict[str, str], path: Path) -> str:
    for name, text in parts.items():
        begin, end = f"<!-- BEGIN GENERATED: {name} -->", f"<!-- END GENERATED: {name} -->"
        if begin not in page or end not in page:
            raise SystemExit(f"{path}: markers {begin!r} and {end!r} not found")
        head, rest = page.split(begin, 1)
        _, tail = rest.split(end, 1)
        page = f"{head}{begin}\n{text.rstrip()}\n{end}{tail}"
    return page


def main(argv: list[str]) -> int:
    stale = []
    for path, parts in _parts().items():
        page = path.read_text()
        new = render(page, parts, path)
        if new != page:
            stale.append(path)
            if "--check" not in argv:
                path.write_text(new)
                print(f"wrote {path.relative_to(ROOT)}")
    if "--check" in argv and stale:
        print(
            f"out of date: {', '.join(str(p.relative_to(ROOT)) for p in stale)}; run docs/gen_config_tables.py",
            file=sys.stderr,
        )
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
