"""Compile a tracker's kernels before its map exists: the C entry point, then what its Python side calls.

A tracker's step is one compiled C entry point (:mod:`solver._kernels.c_entry`); its Python side
calls a few more kernels of its own: the start's proof at ``reset``, procedure 2's look-up in the map,
the DK, the inverse kinematics and the Jacobian, the copies of its flat state.  Compiled in one
process, those share the kernels they call with the entry point (numba types and lowers each callee
once; :mod:`solver.lean_compile` emits its machine code in the outermost kernel only); compiled in
another process later, each would type and lower its callees again (about 20 s of a DK FMU's first
build).

:func:`compile_tracker` compiles them all in this process, without a map: it runs a tracker of the
model on a *toy* map (a few nodes, every label 1), whose arrays have the types of a real map's, so
numba compiles the same signatures.  Its poses mean nothing and are not returned.  The DK FMU's build
calls it in the child that compiles the entry point beside the map (:mod:`cosim.fmus.early_compile`).
"""
from __future__ import annotations

import numpy as np

from .direct_kinematics import dk_all
from .kinematics import ik, jacobians
from .manipulator import HOME_POSE, Manipulator
from .maptensor import MapTensor, default_bounds
from .ordering import DEFAULT_RULE
from .tracker import Tracker

__all__ = ["compile_tracker", "TOY_SHAPE"]

#: Nodes per axis of the toy map (x, y, phi).
TOY_SHAPE = (4, 4, 6)


def toy_map(model: Manipulator) -> MapTensor:
    """A map of the model's default bounds, :data:`TOY_SHAPE` nodes, every label 1: a map's types, no
    map's meaning (a tracker on it compiles what a tracker on a real map compiles)."""
    labels = np.ones(TOY_SHAPE, dtype=np.int8)
    labels.flags.writeable = False              # as a map's: numba types a read-only array apart
    return MapTensor(model=model, posture=1, bounds=default_bounds(model), shape=TOY_SHAPE, rule=DEFAULT_RULE,
                     labels=labels)


def compile_tracker() -> None:
    """Compile the 3-RRR tracker's C entry point and the kernels its Python side calls, in this process
    (the paper's robot on a toy map: the kernels' signatures do not depend on the geometry or the map,
    so every 3-RRR tracker then finds them compiled)."""
    from ._kernels.c_entry import entry
    entry()
    model = Manipulator.paper()
    X0 = np.array(HOME_POSE)
    q0 = ik(model, X0, posture=1)
    jacobians(model, X0, q0)
    toy = toy_map(model)
    dk_all(model, q0, rule=toy.rule)
    toy.near_labels(X0)
    tracker = Tracker(model, toy)
    tracker.reset(X0, q0)
    for k in range(1, 9):               # past the encoder-grid watch of an exact start: the flat state's steps
        tracker.step(ik(model, X0 + np.array([1e-4 * k, 0.0, 0.0]), posture=1), 1e-3)
    tracker.restore(tracker.snapshot())
