"""One byte budget for everything a run keeps to reuse (:class:`ByteBudget`).

A run keeps work it may need again: window dofs, per-window blocks and solvers, the
block-diagonal matrices of the current layout, advections per substep size. Each is a
:class:`Cache` drawn from the domain's one :class:`ByteBudget` (``domain.caches``, sized by
``numerics.cache_mib``). The budget counts every entry's bytes and, when their sum passes
its limit, drops the least recently used entry of any cache, so memory is bounded by one
number whatever mix of caches a scene uses (a mesh's boxes change every few substeps;
the structured channel's window keys are few and small).

An entry is measured when it is put (:func:`nbytes_of`). What it computes lazily afterwards
is not counted until it is put again, and two kinds of entry are never put again: a
layout's per-position arrays made on first use (dofs, masses, cells) and a tensor basis's
single-precision copies. The budget undercounts those by their size. Dropping an entry
only forgets it: whoever holds it keeps using it, and a cache asked for it again rebuilds
it. An entry larger than the whole budget is kept alone.
"""

from __future__ import annotations

import itertools
import weakref
from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Any, TypeVar

import numpy as np
import scipy.sparse as sp

__all__ = ["ByteBudget", "Cache", "nbytes_of"]

Value = TypeVar("Value")
_MISSING = object()


def nbytes_of(value: Any) -> int:
    """Bytes held by ``value``: numpy arrays, scipy sparse matrices, objects with an
    ``nbytes`` attribute, and tuples, lists and dicts of these (by their items); None,
    numbers and strings count 0. Raises TypeError for anything else, so a cache never
    counts an entry it cannot measure as free."""
    if value is None or isinstance(value, (bool, int, float, complex, str, np.generic)):
        return 0
    if isinstance(value, np.ndarray):
        return int(value.nbytes)
    if sp.issparse(value):
        return sum(int(getattr(value, name).nbytes) for name in ("data", "indices", "indptr", "row", "col", "offsets")
                   if isinstance(getattr(value, name, None), np.ndarray))
    if hasattr(value, "nbytes"):
        return int(value.nbytes)
    if isinstance(value, (tuple, list)):
        return sum(nbytes_of(item) for item in value)
    if isinstance(value, dict):
        return sum(nbytes_of(item) for item in value.values())
    raise TypeError(f"cannot measure the bytes of a {type(value).__name__} (give it an nbytes attribute)")


class ByteBudget:
    """Entries of many :class:`Cache` s, bounded together by ``limit`` bytes: least recently
    used dropped first, whichever cache holds them."""

    def __init__(self, limit: int) -> None:
        self._limit = self._checked(limit)
        self.used = 0
        #: (cache id, key) → bytes, least recently used first
        self._entries: OrderedDict[tuple[int, Hashable], int] = OrderedDict()
        self._caches: dict[int, weakref.ref[Cache]] = {}
        self._ids = itertools.count()

    @staticmethod
    def _checked(limit: int) -> int:
        if not (isinstance(limit, (int, np.integer)) and not isinstance(limit, bool) and limit >= 0):
            raise ValueError(f"a byte budget's limit must be a whole number of bytes >= 0, not {limit!r}")
        return int(limit)

    @property
    def limit(self) -> int:
        """Bytes the entries may hold together; lowering it drops entries at once."""
        return self._limit

    @limit.setter
    def limit(self, value: int) -> None:
        self._limit = self._checked(value)
        self._evict(keep=None)

    def cache(self, name: str) -> "Cache":
        """A new, empty cache drawing on this budget (``name`` labels it in :meth:`usage`).
        Its entries leave the budget when the cache is garbage collected."""
        ident = next(self._ids)
        cache = Cache(self, name, ident)
        self._caches[ident] = weakref.ref(cache)
        weakref.finalize(cache, self._forget_cache, ident)
        return cache

    def usage(self) -> dict[str, int]:
        """Bytes held per cache name."""
        out: dict[str, int] = {}
        for (ident, _), size in self._entries.items():
            cache = self._caches[ident]()
            if cache is not None:
                out[cache.name] = out.get(cache.name, 0) + size
        return out

    def __len__(self) -> int:
        return len(self._entries)

    # -- what caches call -----------------------------------------------------------------
    def _charge(self, ident: int, key: Hashable, size: int) -> None:
        entry = (ident, key)
        self.used += size - self._entries.pop(entry, 0)
        self._entries[entry] = size
        self._evict(keep=entry)

    def _touch(self, ident: int, key: Hashable) -> None:
        self._entries.move_to_end((ident, key))

    def _release(self, ident: int, key: Hashable) -> None:
        self.used -= self._entries.pop((ident, key), 0)

    def _evict(self, keep: tuple[int, Hashable] | None) -> None:
        """Drop least recently used entries until the limit holds, never ``keep``."""
        while self.used > self._limit and self._entries:
            entry = next(iter(self._entries))
            if entry == keep:  # the entry just put is the most recent: it is alone
                return
            ident, key = entry
            self._release(ident, key)
            cache = self._caches[ident]()
            if cache is not None:
                cache._values.pop(key, None)

    def _forget_cache(self, ident: int) -> None:
        for entry in [entry for entry in self._entries if entry[0] == ident]:
            self._release(*entry)
        self._caches.pop(ident, None)


class Cache:
    """A mapping whose entries count against a :class:`ByteBudget` (make it with
    :meth:`ByteBudget.cache`). Looking an entry up marks it recently used."""

    def __init__(self, budget: ByteBudget, name: str, ident: int) -> None:
        self.budget, self.name, self._ident = budget, name, ident
        self._values: dict = {}

    def get(self, key: Hashable, default: Any = None) -> Any:
        value = self._values.get(key, _MISSING)
        if value is _MISSING:
            return default
        self.budget._touch(self._ident, key)
        return value

    def __contains__(self, key: Hashable) -> bool:
        return key in self._values

    def __len__(self) -> int:
        return len(self._values)

    def put(self, key: Hashable, value: Value, nbytes: int | None = None) -> Value:
        """Keep ``value`` under ``key`` (replacing any), counted as ``nbytes`` (default
        :func:`nbytes_of`); may drop other entries. Returns ``value``."""
        size = nbytes_of(value) if nbytes is None else int(nbytes)
        self._values[key] = value
        self.budget._charge(self._ident, key, size)
        return value

    def setdefault(self, key: Hashable, build: Callable[[], Value]) -> Value:
        """The entry under ``key``, built by ``build()`` and kept if there is none."""
        value = self.get(key, _MISSING)
        return self.put(key, build()) if value is _MISSING else value

    def pop(self, key: Hashable, default: Any = None) -> Any:
        self.budget._release(self._ident, key)
        return self._values.pop(key, default)

    def items(self) -> list[tuple[Hashable, Any]]:
        """(key, value) of every entry, without marking any as used."""
        return list(self._values.items())

    def retain(self, keys) -> None:
        """Drop every entry whose key is not in ``keys`` (a set)."""
        for key in [key for key in self._values if key not in keys]:
            self.pop(key)

    def clear(self) -> None:
        for key in list(self._values):
            self.pop(key)

    @property
    def nbytes(self) -> int:
        """Bytes this cache's entries are counted as."""
        entries = self.budget._entries
        return sum(entries.get((self._ident, key), 0) for key in self._values)
