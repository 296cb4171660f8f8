"""The one YAML reader of trackflow's files (setups, agent files, optical setups, OpenCV
calibrations): safe, line-aware, and strict about duplicate keys.

Every mapping it returns is a :class:`YamlMap`, a ``dict`` that remembers the line it starts on
and the line of each of its keys, so an error can name the file, the line and the key
(:func:`config_error`). A key given twice in one mapping is refused (plain YAML lets the last
one win silently), and so is text that is not YAML or not UTF-8, each with the file and line::

    doc = read_yaml("lab.yaml")
    if doc["rate_hz"] <= 0:
        raise config_error("lab.yaml", doc, "must be > 0", key="rate_hz")
    # lab.yaml:7: rate_hz: must be > 0
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path

import yaml

from .errors import ConfigError

__all__ = ["YamlMap", "config_error", "dump_yaml", "line_of", "parse_yaml", "read_yaml"]


class YamlMap(dict):
    """A mapping of a YAML file: ``line`` (1-based, 0 when unknown) and ``key_lines``
    (key -> the line of the key)."""

    line = 0
    key_lines: Mapping = {}  # replaced per instance, never changed in place

    def copy(self) -> YamlMap:
        """A shallow copy that keeps the lines."""
        out = YamlMap(self)
        out.line, out.key_lines = self.line, dict(self.key_lines)
        return out


def line_of(item, key=None) -> int:
    """The line of ``key`` in the mapping ``item`` (else of ``item`` itself); 0 when unknown
    (``item`` not read from a file)."""
    if key is not None:
        line = getattr(item, "key_lines", {}).get(key)
        if line:
            return line
    return getattr(item, "line", 0)


def config_error(source, item, message: str, key=None) -> ConfigError:
    """A :class:`~trackflow.errors.ConfigError` naming ``source`` (the file), the line of
    ``key`` in ``item`` (or of ``item``) and ``key``."""
    return ConfigError(message, source, line_of(item, key), key)


class _LineLoader(yaml.SafeLoader):
    """A safe loader making :class:`YamlMap` mappings and refusing duplicate keys."""

    source = "<yaml>"


def _construct_map(loader: _LineLoader, node) -> YamlMap:
    seen: dict = {}
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=True)
        line = key_node.start_mark.line + 1
        try:
            first = seen.get(key)
        except TypeError:  # an unhashable key: construct_mapping reports it
            continue
        if first is not None:
            err = ConfigError(f"duplicate key {key!r} (first on line {first})", loader.source, line)
            err.key = str(key)
            raise err
        seen[key] = line
    m = YamlMap(loader.construct_mapping(node, deep=True))
    m.line, m.key_lines = node.start_mark.line + 1, seen
    return m


_LineLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_map)


def parse_yaml(text: str, source="<yaml>", tags: Mapping[str, Callable] | None = None):
    """Parse YAML ``text`` read from ``source`` (named in errors).

    Parameters
    ----------
    text : str
        The document.
    source : str or Path
        The file name errors give.
    tags : mapping, optional
        Extra constructors ``{tag: fn(loader, node)}`` (OpenCV's ``!!opencv-matrix``); the
        loader's ``source`` attribute holds ``source``.

    Returns
    -------
    object
        The document; every mapping in it a :class:`YamlMap`.

    Raises
    ------
    ConfigError
        Invalid YAML or a duplicate key, with the file and line.
    """
    attrs = {"source": str(source)}
    loader = type("_FileLoader", (_LineLoader,), attrs)  # the constructors of one file
    for tag, fn in (tags or {}).items():
        loader.add_constructor(tag, fn)
    try:
        return yaml.load(text, Loader=loader)  # a SafeLoader subclass
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = getattr(exc, "problem", None) or str(exc)
        line = None if mark is None else mark.line + 1
        raise ConfigError(f"invalid YAML: {problem}", source, line) from None


def read_yaml(path, tags: Mapping[str, Callable] | None = None):
    """Read and parse the YAML file ``path`` (see :func:`parse_yaml`).

    An ``OSError`` (no such file, no permission) is passed on as it is; text that is not
    UTF-8 is a :class:`~trackflow.errors.ConfigError`.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"not a UTF-8 text file ({exc.reason})", path) from None
    return parse_yaml(text, path, tags)


class _Dumper(yaml.SafeDumper):
    """The safe dumper, writing :class:`YamlMap` as the plain mapping it is."""


_Dumper.add_representer(YamlMap, _Dumper.represent_dict)


def dump_yaml(doc) -> str:
    """YAML text of ``doc`` (plain data, mappings read by :func:`read_yaml` included), keys
    in their order."""
    return yaml.dump(doc, Dumper=_Dumper, sort_keys=False)
