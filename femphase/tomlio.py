"""TOML in and out: the reader (``tomllib``, or ``tomli`` before Python 3.11) and a writer of
the plain data a scene resolves to (tables, arrays of tables, inline tables and arrays)."""

from __future__ import annotations

import json
import math
import sys

import numpy as np

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = ["TOMLDecodeError", "loads", "parse_value", "to_toml", "toml_key", "toml_value"]

loads = tomllib.loads
TOMLDecodeError = tomllib.TOMLDecodeError


def parse_value(text: str):
    """``text`` as a TOML value (``--set key=VALUE``), or the string itself when it is none."""
    try:
        document = tomllib.loads(f"v = {text}")
    except (tomllib.TOMLDecodeError, RecursionError, ValueError):
        return text
    return document["v"] if set(document) == {"v"} else text


def toml_value(value) -> str:
    """``value`` as a TOML literal (inline tables and arrays; nan and inf as TOML spells them)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(float(value))
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, dict):
        return "{" + ", ".join(f"{toml_key(k)} = {toml_value(v)}" for k, v in value.items()) + "}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    raise TypeError(f"no TOML literal for {value!r}")


def toml_key(key) -> str:
    """A TOML key: bare when it can be, quoted otherwise."""
    key = str(key)
    return key if key and all(c.isascii() and (c.isalnum() or c in "_-") for c in key) else json.dumps(key)


def to_toml(data: dict) -> str:
    """A small TOML writer for the resolved scene (tables, arrays of tables, plain values)."""
    lines = [f"{toml_key(k)} = {toml_value(v)}" for k, v in data.items() if not isinstance(v, (dict, list))]
    for key, table in data.items():
        if isinstance(table, dict):
            lines += ["", f"[{toml_key(key)}]"] + [f"{toml_key(k)} = {toml_value(v)}" for k, v in table.items()
                                                  if v is not None]
        elif isinstance(table, list):
            for item in table:
                lines += ["", f"[[{toml_key(key)}]]"] + [f"{toml_key(k)} = {toml_value(v)}" for k, v in item.items()]
    return "\n".join(lines) + "\n"
