"""The documentation lists what the code registers."""

from pathlib import Path

from femphase.registry import with_registries
from femphase.scene import registries

DOCS = Path(__file__).resolve().parents[1] / "docs"


def test_scenes_md_lists_every_registered_name():
    text = (DOCS / "scenes.md").read_text()
    assert with_registries(text, registries()) == text, "run: python docs/registries.py"
    for registry in registries():
        for name in registry.names():
            assert f"| `{name}` |" in text


def _table_defaults(section: str) -> dict[str, object]:
    """{key: default} of the key/default/meaning table under ``## `[section]```, defaults
    parsed as TOML values."""
    import re

    import tomllib

    text = (DOCS / "scenes.md").read_text()
    body = text.split(f"## `[{section}]`", 1)[1].split("\n## ", 1)[0]
    rows = re.findall(r"^\| `(\w+)`[^|]* \| ([^|]+) \|", body, re.M)
    return {key: tomllib.loads(f"v = {value.strip()}")["v"] for key, value in rows}


def test_the_documented_defaults_are_the_code_defaults():
    from dataclasses import asdict

    from femphase.config import Numerics
    from femphase.model.parameters import ModelParameters

    for section, defaults in (("numerics", asdict(Numerics())), ("model", asdict(ModelParameters()))):
        documented = _table_defaults(section)
        assert set(documented) == set(defaults), section
        for key, value in defaults.items():
            assert documented[key] == value, f"docs/scenes.md [{section}] {key}: {documented[key]!r}, code {value!r}"
