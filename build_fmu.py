"""Build the three FMUs and their reference CSVs: ``python build_fmu.py [options]``.

The command is :func:`cosim.fmus.cli.main` (options and steps in its docstring, ``--help``); the
builds themselves are :mod:`cosim.fmus.builds`, the reference runs :mod:`cosim.fmus.references`,
``--ssp`` the closed loop as ``<out>/RRRClosedLoop.ssp`` (:mod:`cosim.hosts.system_files`).  FMUs go
to ``build/`` next to this file unless ``--out`` says otherwise.
"""
from pathlib import Path

from cosim.fmus.cli import main
from cosim.unit import exit_process

if __name__ == "__main__":
    # the reference runs load FMUs in this process: end without the pythonfmu libraries' finalizers
    exit_process(main(default_out=Path(__file__).resolve().parent / "build"))
