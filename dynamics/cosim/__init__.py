"""Co-simulation of the paper's Figs 2 and 3 through fmpy: ``python -m dynamics.cosim``.

Three FMUs (FMI 2.0 Co-Simulation, built with pythonfmu from ``fmu_src/``): ``RRRDirectKinematics``
(motor angles -> platform pose, the basic-regions tracker), ``ComputedTorqueController`` (measured
joints, rates and the DK pose -> motor torques, sampled at the start of each step and held) and
``RRRPlant`` (motor torques -> joints, rates and the true pose).

Modules, one concept each: ``scenario`` (:class:`Scenario`, a run's parameters), ``wiring`` (the
instances and :data:`CONNECTIONS`, defined once, and the start values), ``master`` (the Fig. 2 loop
:class:`ClosedLoop`, Gauss-Seidel or Jacobi, and the Fig. 3 scheme :func:`simulate_fig3`),
``system_files`` (the loop as libcosim's OspSystemStructure.xml), ``results`` (the time series,
its CSV and plots), ``__main__`` (the command).  The FMUs are driven by the project's one FMU2Slave
driver, :class:`fmu_src.unit.FMUUnit`: it lives on the host side of ``fmu_src`` because the FMU
checks there run FMUs too, and ``fmu_src`` never imports this package.  The batch runner on dask is
:mod:`dynamics.batch`.

Import direction: this package may import :mod:`solver`, the math of :mod:`dynamics` (its public
top-level names), fmpy and the host side of :mod:`fmu_src` (``unit``, ``builds``, ``libcosim``);
never dask.  Nothing in :mod:`solver`, the math of :mod:`dynamics` or :mod:`fmu_src` imports it;
:mod:`dynamics.batch` does.
"""
from fmu_src.builds import FMU_NAMES, build_fmus
from fmu_src.unit import FMUUnit, exit_process, fmus_loaded, remove_extracted

from .master import ClosedLoop, simulate_fig3
from .results import COLUMN_SOURCES, COLUMNS, ClosedLoopResult, plot_closed_loop, write_csv
from .scenario import Scenario
from .system_files import write_osp_system
from .wiring import CONNECTIONS, INSTANCES, start_values

__all__ = ["Scenario", "FMUUnit", "ClosedLoop", "ClosedLoopResult", "build_fmus", "simulate_fig3",
           "start_values", "write_osp_system", "CONNECTIONS", "INSTANCES", "COLUMNS", "COLUMN_SOURCES",
           "FMU_NAMES", "write_csv", "plot_closed_loop", "exit_process", "fmus_loaded", "remove_extracted"]
