"""Scenes: a typed description of a whole simulation and its TOML file format.

`load_scene(path)` validates a file into a `Scene`; `Scene.build()` turns it into the solver's
objects."""

from .model import (
    SCHEMA,
    BuiltScene,
    Receiver,
    Scene,
    SceneError,
    SceneTooLargeError,
    load_scene,
    parse_scene,
    render_stride,
    schema_markdown,
)
from .schema import ConfigError

__all__ = [
    "SCHEMA",
    "BuiltScene",
    "ConfigError",
    "Receiver",
    "Scene",
    "SceneError",
    "SceneTooLargeError",
    "load_scene",
    "parse_scene",
    "render_stride",
    "schema_markdown",
]
