"""Registries: the names a scene may use for domains, flows, time schemes and observables.

A registry maps a name to a class or builder. Scenes name entries (``[domain] kind = "mesh"``,
``flow = {type = "shear", …}``, ``numerics.scheme = "euler"``, ``output.observables``); an
unknown name raises :class:`~femphase.errors.SceneError` listing the registered ones, and
``docs/scenes.md`` lists every registry from the entries' docstrings
(:func:`markdown` of :func:`femphase.scene.registries`, written by ``python docs/registries.py``
and checked by ``tests/test_docs.py``).

Adding an entry is one decorated definition::

    @FLOWS.register("vortex")
    def vortex(spec, domain): ...

Entries defined outside femphase reach the command line and Dask workers by name: the modules
listed in the environment variable ``FEMPHASE_IMPORT`` (comma-separated; ``femphase --import``
sets it) are imported before a scene is read (:func:`import_extensions`).
"""

from __future__ import annotations

import importlib
import inspect
import os
import re
import sys
from contextlib import contextmanager
from types import ModuleType
from typing import Callable, Generic, Iterable, Iterator, TypeVar

from femphase.errors import FemphaseError, SceneError

__all__ = ["EXTENSIONS_VARIABLE", "MARKERS", "Registry", "blamed", "import_extensions", "import_module", "markdown",
           "users_definition", "with_registries"]

#: The environment variable naming the modules that register entries, comma-separated.
EXTENSIONS_VARIABLE = "FEMPHASE_IMPORT"

T = TypeVar("T")


class Registry(Generic[T]):
    """Name → entry, with the scene key that names it (for error messages)."""

    def __init__(self, title: str, key: str) -> None:
        self.title, self.key = title, key
        self._entries: dict[str, T] = {}

    def register(self, name: str) -> Callable[[T], T]:
        """Decorator: register the decorated class or function under ``name``."""
        def decorate(entry: T) -> T:
            if name in self._entries:
                raise ValueError(f"{self.title}: {name!r} is registered twice")
            self._entries[name] = entry
            return entry
        return decorate

    def unregister(self, name: str) -> None:
        """Remove an entry (for tests and notebooks that register temporary entries)."""
        del self._entries[name]

    def get(self, name: object, key: str | None = None) -> T:
        """The entry called ``name``; SceneError (naming ``key``) if there is none."""
        if not isinstance(name, str) or name not in self._entries:
            raise SceneError(key or self.key, name, f"one of {self.names()} (an entry of your own module is one "
                             f"once the module is imported: femphase --import MODULE, or {EXTENSIONS_VARIABLE})")
        return self._entries[name]

    def names(self) -> tuple[str, ...]:
        return tuple(self._entries)

    def origin(self, name: str) -> str | None:
        """``module.qualname`` of an entry defined outside femphase (the user's own module),
        else None: a fault of the user's entry is reported naming it, one of femphase's own
        is a bug."""
        return users_definition(self._entries[name])

    def __contains__(self, name: object) -> bool:
        return name in self._entries

    def summary(self, name: str) -> str:
        """The first paragraph of the entry's docstring, on one line."""
        doc = inspect.getdoc(self._entries[name]) or ""
        return " ".join(doc.split("\n\n")[0].split())


def users_definition(entry: object) -> str | None:
    """``module.qualname`` of a class or function defined outside femphase (the user's own
    module), else None."""
    module = getattr(entry, "__module__", None) or ""
    if module == "femphase" or module.startswith("femphase."):
        return None
    return f"{module}.{getattr(entry, '__qualname__', repr(entry))}"


@contextmanager
def blamed(origin: str | None, error: Callable[[Exception], Exception]) -> Iterator[None]:
    """Within the block, an exception of the user's entry defined at ``origin`` is raised as
    ``error(exc)``, which names the entry; femphase's own errors, and every exception where
    ``origin`` is None (femphase's own entry: a bug), pass as they are."""
    try:
        yield
    except Exception as exc:
        if origin is None or isinstance(exc, FemphaseError):
            raise
        raise error(exc) from exc


#: A Sphinx cross-reference role in a docstring (``:meth:`~a.b```), which markdown does not render.
_ROLE = re.compile(r":(?:meth|func|data|class|attr|mod|exc):`~?([^`]+)`")


def markdown(registries: Iterable[Registry]) -> str:
    """One markdown table per registry: name and summary of every entry (cross-reference
    roles of the docstrings as plain code)."""
    blocks = []
    for registry in registries:
        lines = [f"### {registry.title} (`{registry.key}`)", "", "| name | what it is |", "|---|---|"]
        for name in registry.names():
            summary = _ROLE.sub(r"`\1`", registry.summary(name)).replace("|", "\\|")
            lines.append(f"| `{name}` | {summary} |")
        blocks.append("\n".join(lines))
    return "\n\n".join(blocks)


MARKERS = ("<!-- registries -->", "<!-- /registries -->")


def with_registries(document: str, registries: Iterable[Registry]) -> str:
    """``document`` with the text between its :data:`MARKERS` replaced by :func:`markdown`."""
    begin, end = MARKERS
    head, _, rest = document.partition(begin)
    _, _, tail = rest.partition(end)
    return f"{head}{begin}\n{markdown(registries)}\n{end}{tail}"


def import_extensions(names: str | None = None) -> None:
    """Import the modules ``names`` (comma-separated; default: :data:`EXTENSIONS_VARIABLE`'s
    value), whose definitions register entries (:func:`import_module`). SceneError (key
    ``--import``) naming a module that cannot be imported, and why."""
    names = os.environ.get(EXTENSIONS_VARIABLE, "") if names is None else names
    for name in (part.strip() for part in names.split(",")):
        if not name or name in sys.modules:
            continue
        try:
            import_module(name)
        except (Exception, SystemExit) as exc:  # importing runs the user's module: it may raise anything
            raise SceneError("--import", name, f"an importable module of femphase extensions ({type(exc).__name__}: "
                             f"{exc}; it is looked up on PYTHONPATH, then in the working directory; named by --import "
                             f"or the environment variable {EXTENSIONS_VARIABLE} = {names!r})") from None


def import_module(name: str) -> ModuleType:
    """The module ``name``, imported from ``sys.path`` or, failing that, from the working
    directory (the ``femphase`` command does not put it on the path, as ``python -m``
    would). Raises what the import raises."""
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as exc:
        if exc.name != name.split(".")[0] or os.getcwd() in sys.path:
            raise
        sys.path.append(os.getcwd())
        return importlib.import_module(name)
