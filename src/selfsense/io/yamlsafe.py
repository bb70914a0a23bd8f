"""YAML reading for every user-written file (``rig.yaml``, the pipeline config): safe and bounded.

* ``yaml.SafeLoader`` (no Python objects), plus YAML 1.2 floats (``1e-3`` without a dot is a number);
* **aliases refused** (``*name`` and merge keys ``<<: *name``): a few lines of nested aliases ("billion laughs")
  expand to gigabytes as soon as anything walks the data, and no selfsense file needs them;
* **a key written twice in one mapping refused** (PyYAML would keep the last value silently: a second
  ``shunt_resistance_ohm:`` line further down a rig file would change every charge without a word);
* a size limit on the text (these files are a few kB).
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import yaml

__all__ = ["NoAliasLoader", "YamlInputError", "load_yaml_text", "load_yaml_file", "MAX_YAML_BYTES"]

MAX_YAML_BYTES = 1 << 20


class YamlInputError(ValueError):
    """A user-written YAML file that cannot be read safely (alias, syntax, size, encoding); one-line message."""

    def __init__(self, file: str, what: str):
        self.file, self.what = file, what
        super().__init__(f"{file}: {what}")


class NoAliasLoader(yaml.SafeLoader):
    """SafeLoader that refuses aliases and reads ``1e-3`` (no dot) as a float, as YAML 1.2 does."""

    def compose_node(self, parent, index):  # noqa: D401 - PyYAML hook
        if self.check_event(yaml.events.AliasEvent):
            ev = self.peek_event()
            raise yaml.composer.ComposerError(
                None, None, f"YAML aliases (*{ev.anchor}) are not allowed", ev.start_mark)
        return super().compose_node(parent, index)

    def construct_mapping(self, node, deep=False):  # noqa: D401 - PyYAML hook
        if isinstance(node, yaml.MappingNode):
            seen: dict = {}
            for key_node, _ in node.value:
                if not isinstance(key_node, yaml.ScalarNode):   # a collection as key: the base class's own error
                    continue
                key = self.construct_object(key_node)   # a tag without constructor raises its own error here
                if key in seen:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"duplicate key {key!r} (first at line {seen[key].line + 1}, again at line "
                        f"{key_node.start_mark.line + 1}): each key once", key_node.start_mark)
                seen[key] = key_node.start_mark
        return super().construct_mapping(node, deep=deep)


NoAliasLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
    |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
    |\.[0-9_]+(?:[eE][-+][0-9]+)?
    |[-+]?\.(?:inf|Inf|INF)
    |\.(?:nan|NaN|NAN))$""", re.X),
    list("-+0123456789."),
)


def load_yaml_text(text: str, file: str = "<yaml>") -> Any:
    """Parse ``text``; raise :class:`YamlInputError` (one line: file, line, what) on aliases or bad syntax."""
    if len(text) > MAX_YAML_BYTES:
        raise YamlInputError(file, f"expected a small YAML file (< {MAX_YAML_BYTES} bytes), found {len(text)} bytes")
    try:
        return yaml.load(text, Loader=NoAliasLoader)  # noqa: S506 (SafeLoader subclass)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark is not None else "unknown position"
        prob = str(getattr(e, "problem", "") or "")
        if prob.startswith("duplicate key"):
            raise YamlInputError(file, f"expected each key once per mapping, found a {prob.split(': each')[0]}"
                                 ) from None
        if "aliases" in prob:
            raise YamlInputError(file, f"expected no YAML aliases/anchors references, found one at {where} "
                                       f"({prob})") from None
        raise YamlInputError(file, f"expected valid YAML, found a syntax error at {where}"
                                   + (f" ({prob})" if prob else "")) from None


def load_yaml_file(path: str | Path) -> Any:
    """Read and parse a YAML file with :func:`load_yaml_text` (size checked before reading)."""
    p = Path(path)
    try:
        size = p.stat().st_size
    except OSError as e:
        raise YamlInputError(str(p), f"expected a readable file, found {type(e).__name__}: {e.strerror}") from None
    if size > MAX_YAML_BYTES:
        raise YamlInputError(str(p), f"expected a small YAML file (< {MAX_YAML_BYTES} bytes), found {size} bytes")
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError as e:
        raise YamlInputError(str(p), f"expected UTF-8 text, found an undecodable byte at {e.start}") from None
    return load_yaml_text(text, str(p))
