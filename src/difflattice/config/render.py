"""What is generated from the declarations: Markdown tables for the docs and argparse options.

Nothing here knows a particular config: a page or a parser asks for the tables or options of the
section classes it documents, so the keys are written down once, in their dataclass.
"""

from __future__ import annotations

import argparse
import inspect
from collections.abc import Iterable
from typing import Any

from .core import REQUIRED, Spec, _Invalid, _show, specs


def _default_cell(s: Spec) -> str:
    if s.default is REQUIRED:
        return "**required**"
    if s.default is None:
        return "—"
    return f"`{_show(s.default)}`"


def _doc_first_paragraph(cls: type) -> str:
    doc = inspect.getdoc(cls) or ""
    return " ".join(doc.split("\n\n")[0].split())


def markdown_table(cls: type, *, heading: str | None = None, level: int = 3, skip: Iterable[str] = ()) -> str:
    """One section's keys as a Markdown table (key, type, default, unit, allowed, meaning), under
    a heading `[section]` (or `heading`) and the first paragraph of the class docstring; the keys
    in `skip` are left out (e.g. a union variant's shared keys, tabled once for all)."""
    skip = set(skip)
    title = heading if heading is not None else f"`[{getattr(cls, 'SECTION', '')}]`"
    lines = [f"{'#' * level} {title}", ""]
    intro = _doc_first_paragraph(cls)
    if intro:
        lines += [intro, ""]
    lines += ["| key | type | default | unit | allowed | meaning |", "|---|---|---|---|---|---|"]
    for s in specs(cls):
        if s.name in skip:
            continue
        allowed = s.allowed()
        if s.unit and allowed.endswith(" " + s.unit):
            allowed = allowed[: -len(s.unit) - 1]
        meaning = s.doc.replace("|", "\\|")
        lines.append(
            f"| `{s.name}` | {s.type_name} | {_default_cell(s)} | {s.unit or '—'} | "
            f"{allowed.replace('|', chr(92) + '|')} | {meaning} |"
        )
    return "\n".join(lines) + "\n"


def markdown_tables(classes: Iterable[type], *, level: int = 3) -> str:
    """Tables of several sections, one after another."""
    return "\n".join(markdown_table(c, level=level) for c in classes)


# --------------------------------------------------------------------------------------------
# argparse
# --------------------------------------------------------------------------------------------


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows every option's default (`(default: ...)`), except where the help text already says
    it, for flags (off unless given) and for required options and positionals. A description or
    epilog with line breaks is kept as written (e.g. `keys_help`); others are wrapped."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        if "\n" in text:
            return "".join(indent + line for line in text.splitlines(keepends=True))
        return super()._fill_text(text, width, indent)

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if "default" in text.lower() or "%(default)" in text:
            return text
        if not action.option_strings or action.required or action.default in (None, argparse.SUPPRESS):
            return text
        if isinstance(action, (argparse._StoreTrueAction, argparse._StoreFalseAction)):
            return text
        return text + " (default: %(default)s)"


class Parser(argparse.ArgumentParser):
    """An `ArgumentParser` whose help shows the defaults (sub-parsers inherit it)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)


def keys_help(classes: Iterable[type], *, width: int = 100) -> str:
    """A compact plain-text list of the declared keys of config sections (for an epilog):
    `[section]` then `key = default [unit]` (or `key (required)`), wrapped to `width`."""
    import textwrap

    lines = []
    for cls in classes:
        items = []
        for s in specs(cls):
            unit = f" [{s.unit}]" if s.unit else ""
            if s.default is REQUIRED:
                items.append(f"{s.name} (required){unit}")
            elif s.default is None:
                items.append(f"{s.name}{unit}")
            else:
                items.append(f"{s.name} = {_show(s.default)}{unit}")
        lines += textwrap.wrap(
            f"[{getattr(cls, 'SECTION', '')}] " + ", ".join(items),
            width=width,
            initial_indent="  ",
            subsequent_indent="      ",
            break_on_hyphens=False,
        )
    return "\n".join(lines)


def _parse_text(s: Spec, kind: str, text: str) -> Any:
    if kind == "bool":
        low = text.lower()
        if low in ("true", "1", "yes"):
            return True
        if low in ("false", "0", "no"):
            return False
        raise _Invalid(f"must be true or false, got {text!r}")
    if kind in ("number", "int"):
        try:
            return int(text) if kind == "int" else float(text)
        except ValueError:
            raise _Invalid(f"must be a {'whole number' if kind == 'int' else 'number'}, got {text!r}") from None
    return text


def option_type(s: Spec, kind: str | None = None):
    """An argparse `type=` callable: parses the text and applies the declaration's checks, so a
    bad value is refused by argparse (exit 2, one line naming the option)."""
    kind = kind or s.kind

    def convert(text: str) -> Any:
        try:
            value = _parse_text(s, kind, text)
            if s.kind == "list":
                return s._item(value, 0)
            return s.check(value)
        except _Invalid as e:
            raise argparse.ArgumentTypeError(f"{e.problem.lstrip('= ')}; allowed: {s.allowed()}") from None

    convert.__name__ = s.type_name  # argparse's message: "invalid <name> value"
    return convert


def option_help(s: Spec) -> str:
    unit = f" [{s.unit}]" if s.unit else ""
    return f"{s.doc}{unit}".replace("%", "%%")


def add_options(
    parser: argparse.ArgumentParser | Any,
    cls: type,
    *,
    dest_prefix: str = "",
    only: Iterable[str] | None = None,
    exclude: Iterable[str] = (),
    suppress_defaults: bool = False,
    overrides: dict[str, dict[str, Any]] | None = None,
) -> list[str]:
    """Add one `--key-name` option per declared key of `cls` (to a parser or an argument group);
    returns the dests. The option's type check, default and help come from the declaration.
    `suppress_defaults`: leave unset options out of the namespace (the caller fills defaults).
    `overrides`: per-key extra `add_argument` keywords (e.g. `required`)."""
    dests = []
    wanted = None if only is None else set(only)
    for s in specs(cls):
        if (wanted is not None and s.name not in wanted) or s.name in exclude:
            continue
        flag = "--" + s.name.replace("_", "-")
        dest = f"{dest_prefix}{s.name}"
        kw: dict[str, Any] = {"dest": dest, "help": option_help(s)}
        default = None if s.default is REQUIRED else (list(s.default) if isinstance(s.default, tuple) else s.default)
        kw["default"] = argparse.SUPPRESS if suppress_defaults else default
        if s.kind == "bool":
            if s.default is True:
                kw["action"] = argparse.BooleanOptionalAction
            else:
                kw["action"] = "store_true"
        elif s.kind == "list":
            kw.update(type=option_type(s, s.items), nargs="+", metavar=s.items.upper() if s.items else "X")
        else:
            kw.update(type=option_type(s), metavar=s.kind.upper() if s.kind != "str" else "TEXT")
            if s.choices:
                kw["choices"] = [c for c in s.choices if c not in s.unavailable]
                kw.pop("metavar")
        if suppress_defaults and s.default not in (REQUIRED, None) and s.kind != "bool":
            kw["help"] += f" (default: {_show(s.default)})".replace("%", "%%")
        elif s.default is None and "default" not in s.doc:
            kw["help"] += " (default: none)"
        kw.update((overrides or {}).get(s.name, {}))
        parser.add_argument(flag, **kw)
        dests.append(dest)
    return dests
