"""Batches of closed-loop co-simulations (Fig. 2) on dask: ``python -m cosim.batch``.

Sweeps over the fields of :class:`cosim.Scenario` (trajectory, gains, communication step,
plant parameter errors, tracker mode, master algorithm, ...); every run is one
:meth:`cosim.ClosedLoop.run` of the three FMUs through fmpy.  The operational manual (the
command line, the config file, the table, a multi-node dask cluster) is docs/batch.md.

Modules, one concept each: ``sweep`` (parsing values and sweeps, the config file; the field types
come from the Scenario dataclass), ``fmu_files`` (the FMU files' identity and their copies on a
node), ``worker`` (one run per task, FMUs loaded once per process), ``execution`` (where the runs
go: this process, a local pool, a dask cluster), ``table`` (the result table, its files and plot),
``cli`` (the command).

Import direction: this package may import :mod:`cosim`, the host side of :mod:`fmu_src`,
:mod:`solver`, dask/distributed, pyarrow and matplotlib; nothing else in the project imports it
(the FMUs never bundle it).
"""
from cosim import FMU_NAMES

from .cli import main, main_and_exit
from .execution import default_workers, local_cluster, run_batch
from .fmu_files import cache_root, fmu_spec, materialize, sha256_file
from .sweep import (BATCH_OPTIONS, DEFAULTS, INT_FIELDS, SCENARIO_FIELDS, STR_FIELDS, VEC_FIELDS, ConfigError, expand,
                    field_name, load_config, parse_sweep_arg, parse_value)
from .table import COLUMNS, METRIC_COLUMNS, BatchResult, plot_summary, scenario_columns, write_table
from .worker import BRANCH_TOL, STATE, FMUBuildConflict, failed_row, get_loop, run_task, worker_state

__all__ = ["SCENARIO_FIELDS", "DEFAULTS", "INT_FIELDS", "STR_FIELDS", "VEC_FIELDS", "BATCH_OPTIONS", "BatchResult",
           "ConfigError", "FMUBuildConflict", "expand", "field_name", "parse_value", "parse_sweep_arg",
           "load_config", "fmu_spec", "sha256_file", "cache_root", "materialize", "run_task", "failed_row",
           "get_loop", "run_batch", "write_table", "plot_summary", "scenario_columns", "worker_state",
           "local_cluster", "default_workers", "main", "main_and_exit", "COLUMNS", "METRIC_COLUMNS",
           "FMU_NAMES", "STATE", "BRANCH_TOL"]
