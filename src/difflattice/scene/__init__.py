"""Scenes: a typed description of a whole simulation and its TOML file format.

`load_scene(path)` validates a file into a `Scene` (a frozen spec of typed sections; transducers
and objects are tagged unions: `type` / `shape` picks the class, `scene.schema`);
`Scene.build()` turns it into the solver's objects."""

from .model import (
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
from .schema import (
    OBJECT,
    TRANSDUCER,
    ConfigError,
    DiscTransducer,
    LineTransducer,
    Object,
    Transducer,
)

__all__ = [
    "OBJECT",
    "TRANSDUCER",
    "DiscTransducer",
    "LineTransducer",
    "Object",
    "Transducer",
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
