"""The documentation lists what the code registers."""

import re
import subprocess
from pathlib import Path

import pytest

from femphase.registry import with_registries
from femphase.scene import registries

DOCS = Path(__file__).resolve().parents[1] / "docs"


def test_scenes_md_lists_every_registered_name():
    text = (DOCS / "scenes.md").read_text()
    assert with_registries(text, registries()) == text, "run: python docs/registries.py"
    for registry in registries():
        for name in registry.names():
            assert f"| `{name}` |" in text
    registered = text.split("<!-- registries -->", 1)[1].split("<!-- /registries -->", 1)[0]
    assert not re.search(r":(meth|func|data|class|attr|mod|exc):`", registered), \
        "a Sphinx role, which markdown shows raw"


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


def test_the_readme_table_is_rendered_from_the_benchmark_results():
    """README.md's accuracy and speed table is what benchmarks/summary.py renders from the
    result files (so a number in it is a number a benchmark wrote)."""
    import importlib.util
    import sys

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "summary.py"
    spec = importlib.util.spec_from_file_location("benchmark_summary", path)
    summary = sys.modules[spec.name] = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(summary)
    readme = summary.README.read_text()
    assert summary.with_table(readme, summary.table()) == readme, "run: python benchmarks/summary.py"


def test_the_readme_is_a_front_page():
    """At most 150 lines, starting with the two commands a new machine needs."""
    lines = (Path(__file__).resolve().parents[1] / "README.md").read_text().splitlines()
    assert len(lines) <= 150
    commands = [line for line in lines[:6] if line.startswith("pip install")]
    assert len(commands) == 2 and "femphase run" in commands[0] and "pytest" in commands[1]


#: Numbered stretches of work (the word session or issue and a number): history, which belongs in git and
#: CHANGELOG.md, never in the files that describe the present.
WORK_PERIOD = re.compile(r"\b(session|issue)[ _-]?\d+", re.IGNORECASE)


def test_no_tracked_file_names_a_work_period():
    root = Path(__file__).resolve().parents[1]
    if not (root / ".git").exists():
        pytest.skip("needs the git work tree to list the tracked files")
    listed = subprocess.run(["git", "ls-files", "-z"], cwd=root, capture_output=True, check=True)
    found = []
    for name in listed.stdout.decode().split("\0"):
        path = root / name
        if not name or not path.is_file():
            continue
        if WORK_PERIOD.search(name):
            found.append(f"{name} (its name)")
            continue
        text = path.read_bytes()
        if b"\0" in text[:4096]:
            continue  # binary (figures, HDF5)
        for number, line in enumerate(text.decode(errors="replace").splitlines(), 1):
            if WORK_PERIOD.search(line):
                found.append(f"{name}:{number}: {line.strip()[:100]}")
    assert not found, "\n".join(found[:40])


def _toctree_entries(page: Path) -> list[Path]:
    """The pages the ``{toctree}`` blocks of a MyST page list (``:glob:`` patterns expanded),
    as paths of .md files; entries are relative to the page's folder, or to docs/ with a
    leading "/"."""
    import re

    pages = []
    blocks = re.findall(r"^(`{3,}|:{3,})\{toctree\}[^\n]*\n(.*?)^\1[ \t]*$", page.read_text(), re.MULTILINE | re.DOTALL)
    for _, body in blocks:
        glob = re.search(r"^:glob:", body, re.MULTILINE) is not None
        for line in body.splitlines():
            line = line.strip()
            if not line or line.startswith(":"):
                continue
            titled = re.fullmatch(r".*<(.+)>", line)  # "Title <target>"
            target = titled.group(1) if titled else line
            if re.match(r"\w+://", target) or target == "self":
                continue
            base = DOCS if target.startswith("/") else page.parent
            target = target.lstrip("/")
            if glob and any(ch in target for ch in "*?["):
                pages += sorted(base.glob(target + ".md"))
            else:
                pages.append(base / f"{target}.md")
    return pages


def test_every_page_is_in_the_site():
    """Every docs/*.md is reachable from docs/index.md through toctrees, and every toctree
    entry is a page that exists: what the site's build (-W) would stop on, checked without
    building it."""
    seen, queue = set(), [DOCS / "index.md"]
    while queue:
        page = queue.pop()
        for entry in _toctree_entries(page):
            assert entry.exists(), f"{page.relative_to(DOCS)}: toctree entry {entry.relative_to(DOCS)} does not exist"
            if entry not in seen:
                seen.add(entry)
                queue.append(entry)
    missing = sorted(page.name for page in DOCS.glob("*.md") if page.name != "index.md" and page not in seen)
    assert not missing, f"add to a toctree in docs/index.md: {missing}"
