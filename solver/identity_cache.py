"""Derived data of a frozen model, built once per object and kept beside it, never on it.

The compiled kernels take flat arrays ("packs") derived from frozen objects: a
:class:`solver.Manipulator`'s model pack and DK constants, a
:class:`dynamics.DynamicParameters`' body rows...  Such data is *explicit* (in the
spirit of Pinocchio's ``model.createData()``): a named function builds it from the
model, and the kernels receive it as arguments.  Building it costs tens of
microseconds, far more than a kernel call, so the public functions that are called
at every step (1 ms) must not rebuild it each time; :func:`by_identity` turns such a
builder into a cached one.

Why a cache keyed by identity, not by value or an attribute on the object:

* the objects are frozen (their arrays read-only), so data derived from one object
  stays valid for as long as that object lives;
* some of them compare by value but are not hashable (:class:`dynamics.DynamicParameters`
  has ``__hash__ = None``), so a value-keyed ``lru_cache`` would need a key built
  from all the arrays at every call, which costs what the cache should save;
* an entry is dropped when its object is garbage collected (a weak reference with a
  callback), so the cache never holds a model alive nor grows without bound;
* nothing is written onto the frozen object.
"""
from __future__ import annotations

import weakref
from functools import wraps
from typing import Callable, TypeVar

__all__ = ["by_identity"]

T = TypeVar("T")


def by_identity(build: Callable[[object], T]) -> Callable[[object], T]:
    """``build(obj)`` cached per object (by ``id``, checked by a weak reference).

    Parameters
    ----------
    build : callable ``build(obj) -> data``
        Derives the data of one frozen, weak-referenceable object.

    Returns
    -------
    callable ``get(obj) -> data``
        The data of ``obj``: built on the first call for that object, the same object on the
        next calls; the entry goes when ``obj`` is collected.  ``get.cache_size()`` is the
        number of live entries.
    """
    cache: dict[int, tuple[weakref.ref, T]] = {}

    def _drop(ref, key):
        entry = cache.get(key)
        if entry is not None and entry[0] is ref:
            del cache[key]

    @wraps(build)
    def get(obj, _lookup=cache.get, _id=id):
        entry = _lookup(_id(obj))
        if entry is not None and entry[0]() is obj:
            return entry[1]
        data = build(obj)
        key = _id(obj)
        cache[key] = (weakref.ref(obj, lambda ref, key=key: _drop(ref, key)), data)
        return data

    get.cache_size = lambda: len(cache)
    return get
