"""The closed loop as system files for other co-simulation masters: libcosim's OspSystemStructure.xml
(:func:`write_osp_system`) and an SSP 1.0 package (:func:`write_ssp_system`), both from
:data:`~cosim.loop.wiring.CONNECTIONS` and :func:`~cosim.loop.wiring.start_values`."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from cosim.fmus.builds import FMU_NAMES
from cosim.hosts.libcosim import write_osp_system_structure
from cosim.hosts.ssp import write_ssp

from ..fmus.robot_build import fmu_model, fmu_robot
from ..loop.scenario import Scenario, robot_scenario
from ..loop.wiring import CONNECTIONS, INSTANCES, start_values

__all__ = ["write_osp_system", "write_ssp_system", "write_closed_loop_ssp", "SSP_NAME"]

#: File name of the closed loop's SSP package (next to the FMUs: ``build/RRRClosedLoop.ssp``).
SSP_NAME = "RRRClosedLoop.ssp"


def _values(sc: Scenario, paths: dict) -> dict:
    """The start values of ``sc`` for the robot the DK FMU of ``paths`` was built for."""
    model = fmu_model(paths[INSTANCES["dk"]])
    return {k: {n: (int(v) if isinstance(v, (int, np.integer)) else float(v)) for n, v in d.items()}
            for k, d in start_values(sc, model).items()}


def write_osp_system(paths: dict, folder, scenario: Scenario | None = None) -> Path:
    """The closed loop as libcosim's OspSystemStructure.xml in ``folder`` (instances dk, controller, plant).

    ``paths``: {FMU name: path}.  The connections are :data:`~cosim.loop.wiring.CONNECTIONS`,
    the initial values :func:`~cosim.loop.wiring.start_values`.  libcosim's fixed-step algorithm
    steps all FMUs from the same inputs and then moves the outputs along the connections: the
    ``order="jacobi"`` scheme of :class:`cosim.ClosedLoop`.
    """
    sc = robot_scenario(fmu_robot(paths[INSTANCES["dk"]])) if scenario is None else scenario
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    return write_osp_system_structure(
        folder / "OspSystemStructure.xml", {inst: paths[name] for inst, name in INSTANCES.items()},
        base_step_size=sc.h, connections=CONNECTIONS, initial_values=_values(sc, paths))


def write_ssp_system(paths: dict, path, scenario: Scenario | None = None) -> Path:
    """The closed loop as the SSP 1.0 package ``path`` (e.g. ``build/RRRClosedLoop.ssp``).

    ``paths``: {FMU name: path}; the FMUs go inside the package.  Components dk, controller, plant
    (:data:`~cosim.loop.wiring.INSTANCES`), the connections
    :data:`~cosim.loop.wiring.CONNECTIONS`, and the scenario's parameters and initial inputs
    (:func:`~cosim.loop.wiring.start_values`: the DK FMU's joints q1..q3 are those of the start
    pose) as the parameter set :data:`cosim.hosts.ssp.PARAMETER_SET`; the default experiment is
    ``[0, t_end]`` at the step ``h`` (see :mod:`cosim.hosts.ssp`).  Ecos and libcosim step all FMUs
    from the same inputs and then move the outputs along the connections: the ``order="jacobi"``
    scheme of :class:`cosim.ClosedLoop`; OMSimulator's command line (which needs the SSD's
    ``oms:FixedStepMaster`` annotation and ``--stopTime``) runs the ``order="omsimulator"`` one.
    """
    sc = robot_scenario(fmu_robot(paths[INSTANCES["dk"]])) if scenario is None else scenario
    return write_ssp(path, {inst: paths[name] for inst, name in INSTANCES.items()}, connections=CONNECTIONS,
                     parameter_values=_values(sc, paths), name=Path(path).stem, start_time=0.0, stop_time=sc.t_end,
                     step_size=sc.h)


def write_closed_loop_ssp(build_dir, scenario: Scenario | None = None) -> Path:
    """``<build_dir>/RRRClosedLoop.ssp`` from the three FMUs in ``build_dir`` (:func:`write_ssp_system`;
    ``python build_fmu.py --ssp`` and the main command write it after building the FMUs)."""
    build_dir = Path(build_dir)
    paths = {name: build_dir / f"{name}.fmu" for name in FMU_NAMES}
    missing = [p.name for p in paths.values() if not p.is_file()]
    if missing:
        raise ValueError(f"build_dir {str(build_dir)!r}: no {', '.join(missing)}; the SSP needs all three FMUs "
                         f"(python build_fmu.py --ssp, without --only)")
    return write_ssp_system(paths, build_dir / SSP_NAME, scenario)
