"""Build the three FMUs and their reference CSVs: ``python build_fmu.py [options]``.

The command is :func:`fmu_src.cli.main` (options and steps in its docstring, ``--help``); the
builds themselves are :mod:`fmu_src.builds`, the reference runs :mod:`fmu_src.references`.
``--ssp`` also writes the closed loop as ``<out>/RRRClosedLoop.ssp``
(:func:`dynamics.cosim.system_files.write_closed_loop_ssp`).  FMUs go to ``build/`` next to this
file unless ``--out`` says otherwise.
"""
from pathlib import Path

from fmu_src.cli import main
from fmu_src.unit import exit_process


def _write_ssp(out_dir):
    from dynamics.cosim.system_files import write_closed_loop_ssp

    return write_closed_loop_ssp(out_dir)


if __name__ == "__main__":
    # the reference runs load FMUs in this process: end without the pythonfmu libraries' finalizers
    exit_process(main(default_out=Path(__file__).resolve().parent / "build", write_ssp=_write_ssp))
