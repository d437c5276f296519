"""One typed configuration layer: each key is declared once, and validation, defaults, the docs
tables and the command-line options are generated from that declaration.

A section is a frozen dataclass (subclass of `Section`) whose fields are made by `setting(...)`:
kind, default, unit, allowed range or choices, meaning and a fix hint. `parse_section` checks a
parsed TOML table and raises a one-line `ConfigError` (file, key, value, allowed values, fix);
legal but unwise values give a `ConfigWarning`. `markdown_table` writes the docs tables and
`add_options` the argparse options from the same declarations.

Why frozen dataclasses with field metadata rather than pydantic v2: the layer must import in the
JAX-free, dependency-light capture subsystem; our keys are flat tables of scalars with units and
ranges, which fit in ~300 lines of stdlib code; and our error format (one line with the file, the
fix and the allowed range) would otherwise need a translation of pydantic's multi-line errors.
No new dependency is needed. Pure Python: nothing here imports JAX or numpy.
"""

from .core import (
    REQUIRED,
    ConfigError,
    ConfigWarning,
    Section,
    Spec,
    as_dict,
    message,
    parse_section,
    setting,
    show,
    specs,
)
from .render import HelpFormatter, Parser, add_options, keys_help, markdown_table, markdown_tables, option_type
from .unions import TaggedUnion

__all__ = [
    "REQUIRED",
    "ConfigError",
    "ConfigWarning",
    "HelpFormatter",
    "Parser",
    "Section",
    "Spec",
    "TaggedUnion",
    "add_options",
    "as_dict",
    "keys_help",
    "markdown_table",
    "markdown_tables",
    "message",
    "option_type",
    "parse_section",
    "setting",
    "show",
    "specs",
]
