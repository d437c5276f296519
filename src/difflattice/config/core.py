"""Declarations and validation: a config section is a frozen dataclass whose fields carry a `Spec`.

    @dataclass(frozen=True)
    class Solver(Section):
        '''How the fit is solved.'''
        SECTION: ClassVar[str] = "solver"
        max_steps: int = setting(200, kind="int", ge=1, doc="iteration limit", fix="use e.g. 200")

`parse_section(Solver, table, file=path)` checks a parsed TOML table against the declarations and
returns the instance (or raises a one-line `ConfigError`); constructing `Solver(...)` in Python
runs the same checks in `__post_init__`. Warnings (legal but unwise values) are issued as
`ConfigWarning` when a table is parsed.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

KINDS = ("number", "int", "bool", "str", "list", "table")


class _Required:
    def __repr__(self) -> str:
        return "REQUIRED"


REQUIRED: Any = _Required()
"""Default of a key that must be given."""


class ConfigError(ValueError):
    """A configuration that cannot be used. The message is one line naming the file, the key, the
    value, what is allowed and the fix; the command line prints it and exits with code 2."""


class ConfigWarning(UserWarning):
    """A legal but unwise configuration value (one line, naming the key and the better choice)."""


@dataclass(frozen=True)
class Spec:
    """The declaration of one key: kind, default, unit, allowed values, meaning and fix.

    `kind`: "number" (int or float, stored as float), "int", "bool", "str", "table" (a dict,
    checked by its user) or "list" (`items`: "number", "int", "str", "range", a `[lo, hi]` pair
    with lo < hi, or "any", unchecked; stored as a tuple). Bounds `gt`/`ge`/`lt`/`le` apply
    to numbers and ints (and to every number of a list); `choices` to strings (and list items).
    `unavailable`: declared choices this version refuses, with the reason. `warn`: pairs
    (predicate, message) checked on a legal value; the message may use `{value}`. `nullable`:
    None (key absent) is allowed; true when the default is None. `doc`: the meaning (one
    sentence, no unit); `fix`: what to do about a bad value. `union`: for a "table" key or a list
    with items "table", a function giving the `unions.TaggedUnion` whose tables it holds (parsed
    into its sections). `name` is set from the field."""

    kind: str
    default: Any = REQUIRED
    unit: str = ""
    doc: str = ""
    fix: str = ""
    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None
    choices: tuple[str, ...] | None = None
    unavailable: Mapping[str, str] = dataclasses.field(default_factory=dict)
    items: str | None = None
    warn: tuple[tuple[Callable[[Any], bool], str], ...] = ()
    nullable: bool = False
    union: Callable[[], Any] | None = None
    name: str = ""

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"Spec kind {self.kind!r}; allowed: {', '.join(KINDS)}")
        if self.kind == "list" and self.items not in ("number", "int", "str", "range", "any", "table"):
            raise ValueError(
                f"a list Spec needs items = 'number', 'int', 'str', 'range', 'table' or 'any', got {self.items!r}"
            )
        if (self.items == "table") != (self.union is not None) and self.kind != "table":
            raise ValueError("a list of tables needs union = (a function giving the TaggedUnion of its tables)")

    # -- description ----------------------------------------------------------------------------
    @property
    def type_name(self) -> str:
        if self.kind == "list":
            return {
                "number": "list of numbers",
                "int": "list of integers",
                "str": "list of strings",
                "range": "list of [lo, hi] pairs",
                "table": "list of tables",
                "any": "list",
            }[self.items or ""]
        return {"number": "number", "int": "integer", "bool": "boolean", "str": "string", "table": "table"}[self.kind]

    def allowed(self) -> str:
        """The allowed values in words, e.g. `> 0 m`, `0 < x <= 180 deg`, `'l2', 'huber'`."""
        if self.choices is not None:
            return ", ".join(repr(c) for c in self.choices if c not in self.unavailable)
        if self.union is not None:
            u = self.union()
            article = "an" if u.noun[:1] in "aeiou" else "a"
            return f"{u.noun} tables (same keys)" if self.kind == "list" else f"{article} {u.noun} table (same keys)"
        lo = f"> {_num(self.gt)}" if self.gt is not None else f">= {_num(self.ge)}" if self.ge is not None else ""
        hi = f"< {_num(self.lt)}" if self.lt is not None else f"<= {_num(self.le)}" if self.le is not None else ""
        unit = f" {self.unit}" if self.unit else ""
        if lo and hi:
            return f"{lo.split()[1]} {'<' if self.gt is not None else '<='} x {hi}{unit}"
        if lo or hi:
            return f"{lo or hi}{unit}"
        if self.kind == "list" and self.items == "range":
            return "[[lo, hi], ...] with lo < hi" + unit
        if self.kind == "list":
            return {"any": "a list", "number": "finite numbers", "int": "integers", "str": "strings"}[
                self.items or "any"
            ] + unit
        return {"bool": "true or false", "str": "any string", "table": "a table"}.get(
            self.kind, f"any finite {self.type_name}{unit}"
        )

    # -- checking -------------------------------------------------------------------------------
    def check(self, value: Any) -> Any:
        """The value converted to its stored type (lists become tuples); raises `_Invalid` with a
        short description of the problem."""
        if value is None:
            if self.nullable:
                return None
            raise _Invalid("is required")
        if self.kind == "list":
            if isinstance(value, (str, bytes)) or not isinstance(value, (list, tuple)):
                raise _Invalid(f"must be a {self.type_name}, got {_show(value)}")
            return tuple(self._item(v, i) for i, v in enumerate(value))
        if self.kind == "table":
            if self.union is not None:
                return self._section(value)
            if not isinstance(value, dict):
                raise _Invalid(f"must be a table, got {_show(value)}")
            return value
        return self._scalar(value, self.kind)

    def _section(self, v: Any) -> Any:
        """A table of this key's union as its section (a dict is parsed; a section is kept)."""
        assert self.union is not None
        u = self.union()
        if isinstance(v, dict):
            return u.parse(v, where=f"{u.section}")
        if not isinstance(v, u.variants):
            raise _Invalid(f"must be a {u.noun} table, got {_show(v)}")
        return v

    def _item(self, v: Any, i: int) -> Any:
        if self.items == "table":
            return self._section(v)
        if self.items == "any":
            return tuple(v) if isinstance(v, list) else v
        if self.items == "range":
            if not isinstance(v, (list, tuple)) or len(v) != 2:
                raise _Invalid(f"item {i} = {_show(v)} must be a [lo, hi] pair")
            lo, hi = (self._scalar(x, "number") for x in v)
            if not lo < hi:
                raise _Invalid(f"item {i} = {_show(v)} must have lo < hi")
            return (lo, hi)
        return self._scalar(v, self.items or "")

    def _scalar(self, value: Any, kind: str) -> Any:
        if kind == "bool":
            if not isinstance(value, bool):
                raise _Invalid(f"must be true or false, got {_show(value)}")
            return value
        if kind == "str":
            if not isinstance(value, str):
                raise _Invalid(f"must be a string, got {_show(value)}")
            if self.choices is not None and value not in self.choices:
                close = difflib.get_close_matches(value, self.choices, n=1)
                hint = f" (did you mean {close[0]!r}?)" if close else ""
                raise _Invalid(f"= {_show(value)} is not a known choice{hint}")
            if value in self.unavailable:
                raise _Invalid(f"= {_show(value)} is not available in this version: {self.unavailable[value]}")
            return value
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise _Invalid(f"must be a {'whole number' if kind == 'int' else 'number'}, got {_show(value)}")
        if not math.isfinite(value):
            raise _Invalid(f"= {_show(value)}: must be a finite number")
        if kind == "int":
            if isinstance(value, float):
                if not value.is_integer():
                    raise _Invalid(f"must be a whole number, got {_show(value)}")
                value = int(value)
        else:
            value = float(value)
        bad = (
            (self.gt is not None and not value > self.gt)
            or (self.ge is not None and not value >= self.ge)
            or (self.lt is not None and not value < self.lt)
            or (self.le is not None and not value <= self.le)
        )
        if bad:
            raise _Invalid(f"= {_show(value)} is out of range")
        return value

    def warnings_for(self, value: Any) -> list[str]:
        if value is None:
            return []
        return [msg.format(value=_show(value)) for pred, msg in self.warn if pred(value)]


class _Invalid(Exception):
    """A value's problem, in words, without file or key (the caller adds them)."""

    def __init__(self, problem: str):
        super().__init__(problem)
        self.problem = problem


def setting(default: Any = REQUIRED, *, kind: str, **spec: Any) -> Any:
    """A dataclass field declared for the config layer (see `Spec` for the keywords)."""
    if default is None:
        spec.setdefault("nullable", True)
    if isinstance(default, list):
        default = tuple(tuple(v) if isinstance(v, list) else v for v in default)
    s = Spec(kind=kind, default=default, **spec)
    meta = {"config": s}
    if default is REQUIRED:
        return dataclasses.field(default=None, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def specs(cls: type) -> list[Spec]:
    """The declared keys of a section class, in declaration order, with their names."""
    out = []
    for f in dataclasses.fields(cls):
        s = f.metadata.get("config")
        if s is not None:
            out.append(dataclasses.replace(s, name=f.name))
    return out


def message(file: str | Path | None, where: str, spec: Spec | None, problem: str) -> str:
    """The one-line error: `file: [where] problem; allowed: ...; fix: ...`."""
    parts = [f"{file}: [{where}] {problem}" if file else f"[{where}] {problem}"]
    if spec is not None:
        if spec.kind != "bool":
            parts.append(f"allowed: {spec.allowed()}")
        if spec.fix:
            parts.append(f"fix: {spec.fix}")
    return "; ".join(" ".join(p.split()) for p in parts)


class Section:
    """Base of declared config sections: checks every declared field on construction.

    Subclasses are frozen dataclasses with a `SECTION` name and fields made by `setting`."""

    SECTION: ClassVar[str] = ""

    def __post_init__(self) -> None:
        for s in specs(type(self)):
            value = getattr(self, s.name)
            where = f"{self.SECTION}.{s.name}"
            if s.default is REQUIRED and value is None:
                raise ConfigError(message(None, where, s, f"is required: {s.doc}"))
            try:
                checked = s.check(value)
            except _Invalid as e:
                raise ConfigError(message(None, where, s, e.problem)) from None
            object.__setattr__(self, s.name, checked)


def parse_section(
    cls: type, table: Any, *, file: str | Path | None = None, where: str | None = None, warn: bool = True
) -> Any:
    """Check a parsed TOML table against `cls`'s declarations and build it.

    Raises `ConfigError` (one line: file, key, value, allowed values, fix) for an unknown key, a
    wrong type, a value out of range or a missing required key; issues `ConfigWarning` for legal
    but unwise values when `warn`."""
    where = str(where or getattr(cls, "SECTION", ""))
    table = {} if table is None else table
    if not isinstance(table, dict):
        raise ConfigError(message(file, where, None, f"must be a table, got {_show(table)}"))
    declared = {s.name: s for s in specs(cls)}
    for key in table:
        if key not in declared:
            close = difflib.get_close_matches(key, declared, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise ConfigError(
                message(file, f"{where}.{key}", None, f"unknown key{hint}; allowed: {', '.join(declared)}")
            )
    values: dict[str, Any] = {}
    notes: list[str] = []
    for name, s in declared.items():
        if name not in table:
            if s.default is REQUIRED:
                raise ConfigError(message(file, f"{where}.{name}", s, f"is required: {s.doc}"))
            continue
        try:
            values[name] = s.check(_nested(s, table[name], file, f"{where}.{name}"))
        except _Invalid as e:
            raise ConfigError(message(file, f"{where}.{name}", s, e.problem)) from None
        notes += [message(file, f"{where}.{name}", None, m) for m in s.warnings_for(values[name])]
    obj = cls(**values)
    if warn:
        for n in notes:
            warnings.warn(n, ConfigWarning, stacklevel=2)
    return obj


def _nested(s: Spec, value: Any, file: str | Path | None, where: str) -> Any:
    """A key's value with the tables of its union parsed into sections, each error naming its
    place (`objects[0].cut`, `objects[1].parts[2]`); other values as they are."""
    if s.union is None or value is None:
        return value
    u = s.union()
    if s.kind == "table":
        return u.parse(value, file=file, where=where) if isinstance(value, dict) else value
    if not isinstance(value, (list, tuple)):
        return value
    return [u.parse(v, file=file, where=f"{where}[{j}]") if isinstance(v, dict) else v for j, v in enumerate(value)]


def as_dict(obj: Any) -> Any:
    """A section (or a nest of sections) as plain TOML-able data (tuples as lists, None dropped)."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        out = {}
        for f in dataclasses.fields(obj):
            v = as_dict(getattr(obj, f.name))
            if v is not None:
                out[f.name] = v
        return out
    if isinstance(obj, (list, tuple)):
        return [as_dict(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    return obj


def _num(x: float | None) -> str:
    if x is None:
        return ""
    return f"{x:g}"


def _show(value: Any) -> str:
    """A value as it is written in TOML."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return f"{value:g}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_show(v) for v in value) + "]"
    if isinstance(value, dict):
        return "a table"
    return str(value)


show = _show
