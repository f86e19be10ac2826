"""What the FMUs of a robot description carry (host side; ``python build_fmu.py --robot FILE``).

A robot (:class:`solver.robot.Robot`) enters the slaves as one build constant, ``BUILD_ROBOT`` (a dict
written into the staged copy of the slave script, :func:`robot_constant`), and the FMUs carry its
description in ``resources/`` (:func:`stage_robot`).  The DK FMU reads its geometry from the maps it
embeds (built for the robot); the constant gives its start values and description.  The plant and the
controller take the geometry, the checked ``[dynamics]`` and the reference circle from it.
"""
from __future__ import annotations

import json
import re
import zipfile
from pathlib import Path

import numpy as np

from .kernels import Run, Scenario

__all__ = ["robot_constant", "with_robot_constant", "stage_robot", "robot_circle", "robot_slave_scenario",
           "other_robot", "fmu_robot", "fmu_model", "loop_robot"]


def robot_constant(robot, posture: int, loop: bool = False) -> dict:
    """The slaves' ``BUILD_ROBOT`` for ``robot`` started in ``posture``: its name, description digest,
    geometry (``Manipulator.to_dict()``), posture, start pose (:func:`solver.robot.start_pose`) and the DK
    FMU's start tolerance (the tracker's default scaled by the robot's reach over the paper's) and, with a
    ``[tolerance]``, its geometry tolerance (the largest half-width, m: the FMU takes one); with
    ``loop`` (the plant and the controller) also its ``[dynamics]``, checked
    (:meth:`dynamics.DynamicParameters.from_robot`), and its reference circle
    (:func:`solver.robot.default_circle`), whose first point is the start pose."""
    from solver.robot import default_circle, start_pose

    from solver.start import start_tolerance_for

    # the DK FMU's default start tolerance, the tracker's for this robot (scaled with its reach)
    out = {"name": robot.name, "digest": robot.digest, "geometry": robot.model.to_dict(), "posture": int(posture),
           "start": [float(v) for v in start_pose(robot, posture)],
           "start_tolerance": [float(v) for v in start_tolerance_for(robot.model)]}
    if robot.tolerance is not None and not robot.tolerance.zero:    # one half-width: the largest of [tolerance]
        out["geometry_tolerance"] = float(max(robot.tolerance.widths.values()))
    if loop:
        from dynamics import DynamicParameters

        out["dynamics"] = DynamicParameters.from_robot(robot).to_dict()
        circle = default_circle(robot, posture)
        out["circle"] = {"center": list(circle["center"]), "radius": circle["radius"], "phi": circle["phi"]}
    return out


def with_robot_constant(text: str, robot: dict, where) -> str:
    """The slave script ``text`` with its line ``BUILD_ROBOT = None`` set to ``robot`` (``where`` names
    the script in the error when that line is not there exactly once)."""
    text, n = re.subn(r"^BUILD_ROBOT = None$", lambda _m: "BUILD_ROBOT = " + repr(robot),
                      text, flags=re.MULTILINE)
    if n != 1:
        raise RuntimeError(f"{where}: expected one line 'BUILD_ROBOT = None', found {n}")
    return text


def stage_robot(tmp: Path, robot) -> dict[str, Path]:
    """The description an FMU of ``robot`` carries (data files ``{name in resources: file}``):
    ``robot.json`` (as checked) and, when it came from a file, that file as ``robot.toml``."""
    if robot is None:
        return {}
    (tmp / "robot.json").write_text(json.dumps(robot.description, indent=1, sort_keys=True) + "\n")
    files = {"robot.json": tmp / "robot.json"}
    if Path(robot.source).is_file():
        files["robot.toml"] = Path(robot.source)
    return files


def robot_circle(robot, posture: int, n: int):
    """Poses (n, 3) of a circle about ``robot``'s start pose in ``posture`` (radius a 40th of its longest
    leg reach, phi swinging by 0.1 rad: the DK FMU's warm-up) and their joints (n, 3), or (poses, None)
    where the circle leaves that posture's tool space or comes within 0.02 of a singularity."""
    from solver import ik
    from solver.kinematics import singularity_measures
    from solver.robot import start_pose

    X0 = np.array(start_pose(robot, posture))
    r = robot.reach / 40.0
    a = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    X = X0 + np.stack([r * (np.cos(a) - 1.0), r * np.sin(a), 0.1 * np.sin(a)], axis=1)
    q = ik(robot.model, X, posture)
    if not np.all(np.isfinite(q)):
        return X, None
    m = singularity_measures(robot.model, X, q)
    return (X, q) if float(np.min(np.minimum(m.type1, m.type2))) >= 0.02 else (X, None)


def robot_slave_scenario(name: str, constant: dict) -> Scenario:
    """The warm-up of a robot's plant (``RRRPlant``) or controller: 100 steps of 1 ms from its start pose
    at rest (the plant unforced, the controller on its circle)."""
    from solver import Manipulator, ik

    X0 = constant["start"]
    if name == "RRRPlant":
        return Scenario([Run(100, 1e-3, {"x0": X0[0], "y0": X0[1], "phi0": X0[2]})])
    q0 = ik(Manipulator.from_dict(constant["geometry"]), np.array(X0), constant["posture"])
    return Scenario([Run(100, 1e-3, {"q1": q0[0], "q2": q0[1], "q3": q0[2], "x": X0[0], "y": X0[1], "phi": X0[2]})])


def other_robot(fmu: Path, robot) -> bool:
    """Whether the FMU file ``fmu`` was built for another robot than ``robot`` (None: the paper's robot,
    whose FMUs carry no description); True for an unreadable file."""
    try:
        with zipfile.ZipFile(fmu) as z:
            names = z.namelist()
            carried = json.loads(z.read("resources/robot.json")) if "resources/robot.json" in names else None
    except (OSError, zipfile.BadZipFile, ValueError):
        return True
    return carried != (robot.description if robot is not None else None)


def fmu_robot(fmu):
    """The robot an FMU (file or extracted folder) was built for (:class:`solver.robot.Robot`, from its ``resources/robot.json``),
    or None: the paper's robot (its FMUs carry no description)."""
    from solver.robot import robot_from_dict

    fmu = Path(fmu)
    if fmu.is_dir():                                   # an extracted FMU
        path = fmu / "resources" / "robot.json"
        if not path.is_file():
            return None
        data = json.loads(path.read_text())
    else:
        with zipfile.ZipFile(fmu) as z:
            if "resources/robot.json" not in z.namelist():
                return None
            data = json.loads(z.read("resources/robot.json"))
    return robot_from_dict(data, source=f"{fmu}:resources/robot.json")


def fmu_model(fmu):
    """The geometry (a ``Manipulator``) of the robot the FMU file ``fmu`` was built for (the paper's when
    it carries no description)."""
    from solver import Manipulator

    robot = fmu_robot(fmu)
    return robot.model if robot is not None else Manipulator.paper()


def loop_robot(path, what: str):
    """The robot description file ``path`` (None: None, the paper's robot) with the ``[dynamics]`` a closed
    loop needs (``what`` names the command in the message); raises ``solver.robot.RobotDescriptionError``
    (a ValueError) naming the file and the field."""
    if path is None:
        return None
    from dynamics import DynamicParameters
    from solver.robot import load_robot

    robot = load_robot(path)
    DynamicParameters.from_robot(robot, what)
    return robot
