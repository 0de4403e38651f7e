"""Work kept by the content of its input arrays (:class:`ContentCache`).

Some work depends on a model alone: the cuts of its template (:mod:`biplanar_reg.mesh_cuts`),
the modes of a deformation kernel on its mean shape. A batch worker loads the model afresh for
every case, so its arrays are new objects with the same content: keyed by a hash of the
content, the work is done once per worker instead of once per case. Hashing costs about
1 ms per MB (0.5 ms for the vertices and faces of a 7,322-vertex surface); the entries are
shared, so what they hold must not be modified.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Generic, TypeVar

import numpy as np

T = TypeVar("T")


def content_key(*arrays: np.ndarray) -> bytes:
    """A 20-byte hash of the arrays' dtypes, shapes and values."""
    h = hashlib.blake2b(digest_size=20)
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.data)
    return h.digest()


class ContentCache(Generic[T]):
    """The last ``size`` results of a computation, by key (thread-safe; two threads asking for
    the same new key may both compute it)."""

    def __init__(self, size: int = 4) -> None:
        self.size = size
        self._items: OrderedDict[Hashable, T] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key: Hashable, compute: Callable[[], T]) -> T:
        """The result kept for ``key``, else ``compute()`` (kept)."""
        with self._lock:
            if key in self._items:
                self._items.move_to_end(key)
                return self._items[key]
        value = compute()
        with self._lock:
            self._items[key] = value
            while len(self._items) > self.size:
                self._items.popitem(last=False)
        return value

    def clear(self) -> None:
        with self._lock:
            self._items.clear()
