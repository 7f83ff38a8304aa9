"""Sphinx configuration of femphase's documentation site.

Build (warnings are errors):

    pip install -e ".[docs]"
    python -m sphinx -W --keep-going -b html docs docs/_build/html

The Markdown pages (the user guide) are read by MyST; the API reference is generated from the
docstrings by autosummary (docs/api.md) and rendered by autodoc with napoleon. The gallery's
figures are committed (docs/gallery/make_gallery.py regenerates them), so the build runs no
simulation. Sphinx reads only .md and .rst files here: docs/registries.py and the gallery
script are never executed by the build.
"""

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# document the checkout this file is in, whichever femphase is installed
sys.path.insert(0, str(ROOT))

import femphase

project = "femphase"
author = "the femphase developers"
copyright = "the femphase developers"
release = femphase.__version__
version = ".".join(release.split(".")[:2])

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.viewcode",
    "myst_parser",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]
templates_path = ["_templates"]

# -- MyST: the pages are GitHub-flavoured Markdown, read on GitHub as well as here ------------
# anchors of headings as GitHub makes them, for links like outputs.md#particlescsv
myst_heading_anchors = 3
# a code block keeps its language where it elides with "..." (a sweep.json excerpt in
# sweeps.md): Pygments then leaves it uncoloured, which is all this warning would say
suppress_warnings = ["misc.highlighting_failure"]

# -- API reference ------------------------------------------------------------------------
# One page per module, generated recursively from docs/api.md. A module's members are those
# in its __all__ (every module declares one; tests/test_architecture.py); the submodules of a
# package are listed whatever its __all__ says (docs/_templates/autosummary/module.rst).
# A name that a package's __all__ takes from one of its modules (femphase.run.Simulation) is
# described once, on the page of the module that defines it, and the package's page links
# there: described twice, every unqualified reference to it (type hints) would be ambiguous.
autosummary_generate = True
autosummary_ignore_module_all = False
autosummary_imported_members = False
# `python -m femphase.cli` runs the command when imported: autosummary imports every submodule
# it lists, so this one is replaced by a stand-in (and so left out of the reference)
autodoc_mock_imports = ["femphase.cli.__main__"]


def _reexports() -> dict[str, dict[str, str]]:
    """{module: {name: where it is described}} of the classes and functions a
    module's __all__ takes from another femphase module whose __all__ lists them too."""
    import importlib
    import inspect
    import pkgutil

    names = ["femphase"] + [
        info.name
        for info in pkgutil.walk_packages(femphase.__path__, "femphase.")
        if info.name not in autodoc_mock_imports
    ]
    found: dict[str, dict[str, str]] = {}
    for name in names:
        module = importlib.import_module(name)
        for member in getattr(module, "__all__", ()):
            obj = getattr(module, member)
            origin = getattr(obj, "__module__", None) or ""
            if not (inspect.isclass(obj) or inspect.isfunction(obj)) or origin == name:
                continue
            if origin.startswith("femphase.") and member in getattr(importlib.import_module(origin), "__all__", ()):
                # relative to the module's page (autosummary refuses the page's own prefix)
                where = origin.removeprefix(f"{name}.")
                found.setdefault(name, {})[member] = f"{where}.{member}"
    return found


autosummary_context = {"reexports": _reexports()}
autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_member_order = "bysource"
autodoc_typehints = "description"

napoleon_google_docstring = True
napoleon_numpy_docstring = True

# -- HTML -----------------------------------------------------------------------------------
html_theme = "furo"
html_title = f"femphase {release}"
