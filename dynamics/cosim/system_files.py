"""The closed loop as a system file for other co-simulation masters: libcosim's OspSystemStructure.xml."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fmu_src.libcosim import write_osp_system_structure

from .scenario import Scenario
from .wiring import CONNECTIONS, INSTANCES, start_values

__all__ = ["write_osp_system"]


def write_osp_system(paths: dict, folder, scenario: Scenario | None = None) -> Path:
    """The closed loop as libcosim's OspSystemStructure.xml in ``folder`` (instances dk, controller, plant).

    ``paths``: {FMU name: path}.  The connections are :data:`~dynamics.cosim.wiring.CONNECTIONS`,
    the initial values :func:`~dynamics.cosim.wiring.start_values`.  libcosim's fixed-step algorithm
    steps all FMUs from the same inputs and then moves the outputs along the connections: the
    ``order="jacobi"`` scheme of :class:`dynamics.cosim.ClosedLoop`.
    """
    sc = Scenario() if scenario is None else scenario
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    return write_osp_system_structure(
        folder / "OspSystemStructure.xml", {inst: paths[name] for inst, name in INSTANCES.items()},
        base_step_size=sc.h, connections=CONNECTIONS,
        initial_values={k: {n: (int(v) if isinstance(v, (int, np.integer)) else float(v)) for n, v in d.items()}
                        for k, d in start_values(sc).items()})
