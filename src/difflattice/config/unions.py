"""Tagged unions of sections: tables of one array (e.g. a scene's `[[transducers]]`) whose tag
key (`type = "disc"`) picks the section class that declares their keys.

    @dataclass(frozen=True)
    class Line(Transducer):          # Transducer: the keys every variant has, tag field first
        type: str = setting("line", kind="str", choices=("line",), doc="a line of cells")
        n_cells: int | None = setting(None, kind="int", ge=1, doc="source cells")

    TRANSDUCER = TaggedUnion("transducers", "type", (Line, Disc), default="line", noun="transducer")
    TRANSDUCER.parse({"type": "disc", ...}, file=path, where="transducers[0]")  # -> a Disc

Each variant is a `Section` declaring only its own keys (the shared ones in a common base); the
tag is a field whose only choice is the variant's own value. A key of another variant is refused
naming the variants it belongs to (`radius_m is a key of circle objects, not box ones`), an
unknown tag naming the known ones. A key whose value is a table of the union (a `cut`) or a list
of them (`parts`) is declared with `setting(kind="table" | "list", items="table", union=...)` and
parsed into sections by `parse_section`. Pure Python, like the rest of the layer.
"""

from __future__ import annotations

import difflib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .core import REQUIRED, ConfigError, Spec, message, parse_section, show, specs


@dataclass(frozen=True)
class TaggedUnion:
    """Section classes told apart by the value of one key.

    `section`: the array's name (`transducers`); `tag`: the key whose value picks the class
    (`type`); `variants`: the classes, each with a tag field whose default is its own value;
    `default`: the tag of a table that does not give one (None: the tag is required); `noun`: what
    one table is, in messages (`transducer`)."""

    section: str
    tag: str
    variants: tuple[type, ...]
    default: str | None = None
    noun: str = "table"

    def __post_init__(self) -> None:
        for v in self.variants:
            if self.tag not in {s.name for s in specs(v)}:
                raise ValueError(f"{v.__name__} declares no tag field {self.tag!r}")

    @property
    def classes(self) -> dict[str, type]:
        """Tag value -> section class, in declaration order."""
        return {tag_of(v, self.tag): v for v in self.variants}

    def owners(self, key: str) -> list[str]:
        """The tags of the variants that declare `key`."""
        return [t for t, c in self.classes.items() if key in {s.name for s in specs(c)}]

    def parse(self, table: Any, *, file: str | Path | None = None, where: str | None = None, warn: bool = True) -> Any:
        """The section of the variant that `table`'s tag names, checked (`parse_section`); raises
        `ConfigError` (one line: file, key, problem, fix) for a missing or unknown tag and for a
        key of another variant, naming the variants it belongs to."""
        where = where or self.section
        if not isinstance(table, dict):
            raise ConfigError(message(file, where, None, f"must be a table, got {show(table)}"))
        classes = self.classes
        tags = ", ".join(repr(t) for t in classes)
        tag = table.get(self.tag, self.default)
        if tag is None:
            raise ConfigError(
                message(
                    file, f"{where}.{self.tag}", None, f"is required: the {self.noun}'s {self.tag}; allowed: {tags}"
                )
            )
        if not isinstance(tag, str) or tag not in classes:
            close = difflib.get_close_matches(tag, classes, n=1) if isinstance(tag, str) else []
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise ConfigError(
                message(
                    file,
                    f"{where}.{self.tag}",
                    None,
                    f"= {show(tag)} is not a known {self.noun} {self.tag}{hint}; allowed: {tags}",
                )
            )
        cls = classes[tag]
        own = {s.name for s in specs(cls)}
        for key in table:
            if key in own:
                continue
            owners = self.owners(key)
            if owners:
                them = _words([f"{t}" for t in owners])
                raise ConfigError(
                    message(
                        file,
                        f"{where}.{key}",
                        None,
                        f"is a key of {them} {self.noun}s, not {tag} ones: remove it, or set "
                        f"{self.tag} = {show(owners[0])} if this {self.noun} is one",
                    )
                )
        return parse_section(cls, table, file=file, where=where, warn=warn)


def tag_of(cls: type, tag: str) -> str:
    """A variant's own tag value (the default of its tag field)."""
    for s in specs(cls):
        if s.name == tag:
            if s.default is REQUIRED or not isinstance(s.default, str):
                raise ValueError(f"{cls.__name__}.{tag} needs its own value as the default")
            return s.default
    raise ValueError(f"{cls.__name__} declares no tag field {tag!r}")


def union_of(spec: Spec) -> TaggedUnion | None:
    """The union whose tables a `table` key (or a list of tables) holds, or None."""
    ref: Callable[[], TaggedUnion] | None = spec.union
    return None if ref is None else ref()


def _words(items: list[str]) -> str:
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]
