"""The closed loop's wiring (paper Fig. 2), defined once: used by the master and the system files.

Three instances, named after their role: ``dk`` (``RRRDirectKinematics``), ``controller``
(``ComputedTorqueController``) and ``plant`` (``RRRPlant``), in the order of the data flow
(q -> tracker -> pose -> controller -> tau -> plant -> q), which is the Gauss-Seidel order.
:data:`CONNECTIONS` lists every link ``("instance.output", "instance.input")``; the master feeds
each instance's inputs from it (:func:`inputs_of`, :func:`copy_plan`) and the OSP system file
(:mod:`cosim.hosts.system_files`) writes it as is.  :data:`RECORDED` names the outputs the
master reads at every step only to record them.
"""
from __future__ import annotations

import numpy as np

from solver import Manipulator, ik

from .scenario import Scenario

__all__ = ["INSTANCES", "CONNECTIONS", "RECORDED", "inputs_of", "sources_of", "outputs_of", "copy_plan",
           "start_values"]

#: instance -> FMU (model) name, in the order of the data flow (the Gauss-Seidel order).
INSTANCES = {"dk": "RRRDirectKinematics", "controller": "ComputedTorqueController", "plant": "RRRPlant"}

#: The closed loop's connections, "instance.output" -> "instance.input" (OSP / SSP style).
CONNECTIONS = (
    [(f"plant.q{i}", f"dk.q{i}") for i in (1, 2, 3)]
    + [(f"plant.q{i}", f"controller.q{i}") for i in (1, 2, 3)]
    + [(f"plant.dq{i}", f"controller.dq{i}") for i in (1, 2, 3)]
    + [(f"dk.{v}", f"controller.{v}") for v in ("x", "y", "phi")]
    + [(f"controller.tau{i}", f"plant.tau{i}") for i in (1, 2, 3)]
)

#: Outputs the master reads at every step beyond the connected ones, to record them.
RECORDED = {
    "dk": ("region", "n_real", "status", "near_border", "ambiguous", "certain", "uncertain_since"),
    "controller": ("x_ref", "y_ref", "phi_ref_out", "q1_ref", "q2_ref", "q3_ref"),
    "plant": ("x_true", "y_true", "phi_true"),
}


def _split(end: str) -> tuple[str, str]:
    instance, _, variable = end.partition(".")
    return instance, variable


def inputs_of(instance: str) -> tuple[str, ...]:
    """The connected inputs of ``instance``, in the order of :data:`CONNECTIONS`."""
    return tuple(_split(dst)[1] for _, dst in CONNECTIONS if _split(dst)[0] == instance)


def sources_of(instance: str) -> tuple[str, ...]:
    """The ``"instance.output"`` feeding each of :func:`inputs_of` ``(instance)``."""
    return tuple(src for src, dst in CONNECTIONS if _split(dst)[0] == instance)


def outputs_of(instance: str) -> tuple[str, ...]:
    """The outputs of ``instance`` the master reads: the connected ones (first use first), then
    :data:`RECORDED`."""
    connected = [_split(src)[1] for src, _ in CONNECTIONS if _split(src)[0] == instance]
    return tuple(dict.fromkeys([*connected, *RECORDED[instance]]))


def copy_plan(targets, where: dict) -> tuple[tuple[int, int, object, int, int], ...]:
    """How to fill slots ``0..len(targets)-1`` from buffers: ``(a, b, key, c, d)`` means
    ``slots[a:b] = buffer[key][c:d]``.

    ``targets[i]`` is an ``"instance.variable"`` (or None: not filled); ``where`` maps it to
    ``(key, index)`` of the buffer holding it.  Consecutive slots from consecutive places of one
    buffer make one run.
    """
    runs: list[list] = []
    for i, target in enumerate(targets):
        if target is None:
            continue
        key, j = where[target]
        last = runs[-1] if runs else None
        if last is not None and last[1] == i and last[2] == key and last[4] == j:
            last[1], last[4] = i + 1, j + 1
        else:
            runs.append([i, i + 1, key, j, j + 1])
    return tuple(tuple(r) for r in runs)


def start_values(sc: Scenario, model: Manipulator | None = None) -> dict:
    """Parameters and initial inputs of the three instances for a scenario: {instance: {variable: value}}.

    ``model``: the robot's geometry (the FMUs': :func:`cosim.fmus.robot_build.fmu_model`); None: the
    paper's robot."""
    X0 = sc.start_pose
    q0 = ik(Manipulator.paper() if model is None else model, X0, sc.posture)
    if np.isnan(q0[0]):
        raise ValueError(f"scenario: the start pose {X0.tolist()} is outside posture {sc.posture}")
    return {
        "plant": {"x0": X0[0], "y0": X0[1], "phi0": X0[2], "posture": sc.posture,
                  "mass_scale": sc.plant_mass_scale, "substeps": sc.plant_substeps},
        "dk": {"x0": X0[0], "y0": X0[1], "phi0": X0[2], "posture": sc.posture,
               "mode": 0 if sc.tracker_mode == "default" else 1, "q1": q0[0], "q2": q0[1], "q3": q0[2]},
        "controller": {"bandwidth": sc.bandwidth, "damping": sc.damping, "mass_scale": sc.controller_mass_scale,
                       "posture": sc.posture, "center_x": sc.center[0], "center_y": sc.center[1],
                       "radius": sc.radius, "phi_ref": sc.phi, "period": sc.period, "ramp_time": sc.ramp_time,
                       "q1": q0[0], "q2": q0[1], "q3": q0[2], "dq1": 0.0, "dq2": 0.0, "dq3": 0.0,
                       "x": X0[0], "y": X0[1], "phi": X0[2]},
    }
