"""Validation of TOML tables against a schema: key -> (type(s), default, description with unit).

Shared by scene files and fit configs, so both give the same errors: the file, the key, and what
is allowed.
"""

from __future__ import annotations

NUM = (int, float)
REQUIRED = object()


class ConfigError(ValueError):
    """A file that cannot be used: the message names the file, the key and the fix."""


def fail(path, key, msg, error=ConfigError):
    raise error(f"{path}: [{key}] {msg}")


def validate_table(path, schema: dict, table, where: str, error=ConfigError) -> dict:
    """Check keys and types, fill defaults; raise `error` naming the file and the key."""
    if not isinstance(table, dict):
        fail(path, where, f"must be a table, got {type(table).__name__}", error)
    out = {}
    for key, value in table.items():
        if key not in schema:
            fail(path, f"{where}.{key}", f"unknown key; allowed: {', '.join(schema)}", error)
        types = schema[key][0]
        if (types is NUM and isinstance(value, bool)) or not isinstance(value, types):
            tname = "number" if types is NUM else getattr(types, "__name__", str(types))
            fail(path, f"{where}.{key}", f"must be a {tname}, got {value!r} ({schema[key][2]})", error)
        out[key] = value
    for key, (types, default, desc) in schema.items():
        if key not in out:
            if default is REQUIRED:
                fail(path, f"{where}.{key}", f"is required ({desc})", error)
            out[key] = default
    return out


def schema_markdown(schema: dict[str, dict], array_sections=()) -> str:
    """Markdown tables documenting every key, its type, default and unit."""
    lines = []
    for section, keys in schema.items():
        head = f"[[{section}]]" if section in array_sections else f"[{section}]"
        lines += [f"### `{head}`", "", "| key | type | default | meaning (unit) |", "|---|---|---|---|"]
        for k, (types, default, desc) in keys.items():
            tname = "number" if types is NUM else types.__name__
            d = "**required**" if default is REQUIRED else ("—" if default is None else f"`{default}`")
            lines.append(f"| `{k}` | {tname} | {d} | {desc} |")
        lines.append("")
    return "\n".join(lines)
