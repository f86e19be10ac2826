"""The host side: everything that builds FMUs or runs them from outside.  ``python -m cosim``.

The paper's Figs 2 and 3 as a co-simulation of three FMUs (FMI 2.0 Co-Simulation, built with
pythonfmu from the slaves in :mod:`fmu_src`): ``RRRDirectKinematics`` (motor angles -> platform pose,
the basic-regions tracker), ``ComputedTorqueController`` (measured joints, rates and the DK pose ->
motor torques) and ``RRRPlant`` (motor torques -> joints, rates and the true pose).

Sub-packages, one concern each:

* :mod:`cosim.fmus`: building the FMUs (``sources``: where the slaves live; ``packaging``:
  ``build_fmu`` with pythonfmu; ``model_description``; ``native``: the C loader binary; ``checks``:
  ``validate`` and ``smoke_check``; ``builds``: the project's FMUs and ``build_fmus``; ``rpr_build``;
  ``references``: the reference runs and CSVs; ``cli``: ``python build_fmu.py``).
* :mod:`cosim.unit`: :class:`FMUUnit`, the one fmpy ``FMU2Slave`` driver, and the process rules
  of pythonfmu FMUs; :mod:`cosim.simulation`: ``fmpy.simulate_fmu`` that raises on a refused step.
* :mod:`cosim.loop`: the closed loop (``scenario``, ``wiring``, ``master`` of Figs 2-3,
  ``results``: the time series, its CSV and plots).
* :mod:`cosim.hosts`: other co-simulation hosts (``libcosim``, ``ssp``: SSP 1.0 packages,
  ``system_files``: the closed loop as OSP and SSP system files).
* :mod:`cosim.batch`: batches of closed-loop runs on dask, ``python -m cosim.batch``.

Import direction: this package imports :mod:`solver`, :mod:`dynamics`, :mod:`fmu_src`, fmpy,
pythonfmu, libcosimpy and (in :mod:`cosim.batch` only) dask; nothing in those imports it.
"""
from cosim.fmus.builds import FMU_NAMES
from cosim.fmus.fmu_set import build_fmus
from cosim.unit import FMUUnit, exit_process, fmus_loaded, remove_extracted

from .loop.master import ClosedLoop, simulate_fig3
from .loop.results import COLUMN_SOURCES, COLUMNS, ClosedLoopResult, plot_closed_loop, write_csv
from .loop.scenario import Scenario
from .hosts.system_files import write_osp_system
from .loop.wiring import CONNECTIONS, INSTANCES, start_values

__all__ = ["Scenario", "FMUUnit", "ClosedLoop", "ClosedLoopResult", "build_fmus", "simulate_fig3",
           "start_values", "write_osp_system", "CONNECTIONS", "INSTANCES", "COLUMNS", "COLUMN_SOURCES",
           "FMU_NAMES", "write_csv", "plot_closed_loop", "exit_process", "fmus_loaded", "remove_extracted"]
