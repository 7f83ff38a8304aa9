"""The documentation lists what the code registers."""

from pathlib import Path

from femphase.registry import builtin, with_registries

DOCS = Path(__file__).resolve().parents[1] / "docs"


def test_scenes_md_lists_every_registered_name():
    text = (DOCS / "scenes.md").read_text()
    assert with_registries(text) == text, "run: python -m femphase.registry --write docs/scenes.md"
    for registry in builtin():
        for name in registry.names():
            assert f"| `{name}` |" in text
