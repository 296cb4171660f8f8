"""trackflow.yamlfile: the one YAML reader (lines of mappings and keys, duplicate keys refused)."""

from __future__ import annotations

import pytest

from trackflow.errors import ConfigError
from trackflow.yamlfile import YamlMap, config_error, line_of, parse_yaml, read_yaml


def test_mappings_know_their_lines_and_the_lines_of_their_keys():
    doc = parse_yaml("a: 1\nb:\n  c: 2\n\n  d: [1, 2]\nlist:\n  - {x: 1}\n", "f.yaml")
    assert isinstance(doc, YamlMap) and doc.line == 1
    assert line_of(doc, "a") == 1 and line_of(doc, "b") == 2 and line_of(doc, "list") == 6
    assert line_of(doc["b"], "d") == 5 and doc["b"].line == 3
    assert line_of(doc["list"][0], "x") == 7
    assert line_of(doc, "missing") == 1 and line_of({"plain": 1}, "plain") == 0
    copy = doc["b"].copy()
    assert isinstance(copy, YamlMap) and copy == doc["b"] and line_of(copy, "d") == 5
    e = config_error("f.yaml", doc["b"], "must be a list", "c")
    assert str(e) == "f.yaml:3: c: must be a list" and e.line == 3


@pytest.mark.parametrize(
    ("text", "line"),
    [
        ("a: 1\na: 2\n", 2),
        ("top:\n  x: 1\n  y: 2\n  x: 3\n", 4),
        ("- {n: 1, m: 2, n: 3}\n", 1),
    ],
)
def test_a_duplicate_key_is_refused_with_its_line(tmp_path, text, line):
    p = tmp_path / "d.yaml"
    p.write_text(text)
    with pytest.raises(ConfigError, match="duplicate key") as e:
        read_yaml(p)
    assert str(e.value).startswith(f"{p}:{line}: ") and e.value.line == line


def test_invalid_yaml_and_non_utf8_name_the_file(tmp_path):
    p = tmp_path / "bad.yaml"
    p.write_text("a: 1\nb: [\n")
    with pytest.raises(ConfigError, match="invalid YAML") as e:
        read_yaml(p)
    assert str(e.value).startswith(f"{p}:3: ")
    p.write_bytes(b"a: \xff\n")
    with pytest.raises(ConfigError, match="not a UTF-8 text file"):
        read_yaml(p)
    with pytest.raises(FileNotFoundError):
        read_yaml(tmp_path / "nope.yaml")


def test_extra_tags_get_the_source():
    def tag(loader, node):
        return (loader.source, node.start_mark.line + 1)

    doc = parse_yaml("a: 1\nm: !!thing {x: 1}\n", "t.yml", {"tag:yaml.org,2002:thing": tag})
    assert doc["m"] == ("t.yml", 2)
    with pytest.raises(ConfigError, match="could not determine a constructor"):
        parse_yaml("m: !!thing {x: 1}\n", "t.yml")  # tags of one call do not leak into another
