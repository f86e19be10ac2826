"""A reference to a slave module's globals for each time pythonfmu's wrapper runs the module (part of
the FMU runtime: standard library only).

pythonfmu 0.7's C wrapper finds the slave class at every ``fmi2Instantiate`` by importing the slave
module and executing its source again in the module's globals (``findClass`` in
``PySlaveInstance.cpp``).  It then releases a reference to those globals that it never took
(``Py_DECREF`` of the borrowed reference ``PyModule_GetDict`` returns): each instantiation takes one
reference from the module's ``__dict__``.  A module whose functions and classes hold few references to
it (the 3-RPR's slave, a subclass that defines no method) loses its ``__dict__`` at the first
instantiation: the memory is reused (the module's namespace then reads as the slave instance's
attributes), and the next garbage collection, typically inside numba's compiler, crashes the host
with a segmentation fault.  Every slave script therefore calls :func:`hold_globals` at module level:
each execution of the module takes the reference the wrapper will release, and keeps it (a list of
one dict, one entry per instantiation: a few bytes).
"""
from __future__ import annotations

__all__ = ["hold_globals", "held"]

_HELD: list = []


def hold_globals(namespace: dict) -> None:
    """Keep one reference to ``namespace`` (the caller's ``globals()``) for the life of the process."""
    _HELD.append(namespace)


def held(namespace: dict) -> int:
    """How many references :func:`hold_globals` keeps to ``namespace`` (for the tests)."""
    return sum(1 for n in _HELD if n is namespace)
