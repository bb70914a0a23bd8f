"""docs/configuration.md documents exactly the keys of the config schema, with the schema's defaults and allowed
values, and the shipped config.yaml comments name every allowed value of the keys they list."""
from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
SCHEMA = yaml.safe_load((ROOT / "workflow" / "schemas" / "config.schema.yaml").read_text())
DOC = (ROOT / "docs" / "configuration.md").read_text()


def _sections() -> dict[str, dict[str, list[str]]]:
    """section ('' = top level, else the ``## `name:` `` heading) -> {key: table cells} of docs/configuration.md."""
    out: dict[str, dict[str, list[str]]] = {}
    sec = None
    for line in DOC.splitlines():
        m = re.match(r"^## (?:`([a-z_]+):`|Top level)", line)
        if m:
            sec = m.group(1) or ""
            out.setdefault(sec, {})
            continue
        if line.startswith("## "):
            sec = None
        if sec is not None and line.startswith("| `"):
            cells = [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", line.strip().strip("|"))]
            out[sec][cells[0].strip("`")] = cells
    return out


DOCS = _sections()


def _schema_sections():
    top = {k: v for k, v in SCHEMA["properties"].items()}
    yield "", {k: v for k, v in top.items() if v.get("type") != "object"}
    for k, v in top.items():
        if v.get("type") == "object":
            yield k, v["properties"]


@pytest.mark.parametrize("section,props", list(_schema_sections()), ids=lambda x: (x or "top") if isinstance(x, str) else "")
def test_every_schema_key_is_documented_and_no_other(section, props):
    documented = DOCS.get(section)
    assert documented is not None, f"docs/configuration.md has no section for `{section}:`"
    assert set(documented) == set(props), (f"`{section or 'top level'}`: documented {sorted(documented)}, schema "
                                           f"{sorted(props)}")


@pytest.mark.parametrize("section,props", list(_schema_sections()), ids=lambda x: (x or "top") if isinstance(x, str) else "")
def test_documented_defaults_and_allowed_values_match_the_schema(section, props):
    for key, spec in props.items():
        cells = DOCS[section][key]
        kind, default = cells[1], cells[2]
        if "default" in spec and not isinstance(spec["default"], dict):
            want = spec["default"]
            want = {True: "true", False: "false"}.get(want, want) if isinstance(want, bool) else want
            assert f"`{want}`" in default, f"{section}.{key}: schema default {want!r}, docs say {default!r}"
        for value in spec.get("enum", []):
            value = {True: "true", False: "false"}.get(value, value) if isinstance(value, bool) else value
            assert f"`{value}`" in kind, f"{section}.{key}: allowed value {value!r} not documented ({kind!r})"
        for value in spec.get("items", {}).get("enum", []):
            assert f"`{value}`" in kind, f"{section}.{key}: allowed value {value!r} not documented ({kind!r})"


def test_config_yaml_comments_list_every_value_of_h_model_and_regression():
    text = (ROOT / "config.yaml").read_text()
    cal = SCHEMA["properties"]["calibration"]["properties"]
    for key in ("h_model", "regression"):
        block = re.search(rf"^  {key}:.*?(?=^  [a-z_]+:)", text, re.S | re.M).group(0)
        for value in cal[key]["enum"]:
            assert re.search(rf"\b{value}\b", block), f"config.yaml: the comment of {key} does not name {value!r}"
