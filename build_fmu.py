"""Build the three FMUs and their reference CSVs: ``python build_fmu.py [options]``.

The command is :func:`fmu_src.cli.main` (options and steps in its docstring, ``--help``); the
builds themselves are :mod:`fmu_src.builds`, the reference runs :mod:`fmu_src.references`.
FMUs go to ``build/`` next to this file unless ``--out`` says otherwise.
"""
from pathlib import Path

from fmu_src.cli import main
from fmu_src.unit import exit_process

if __name__ == "__main__":
    # the reference runs load FMUs in this process: end without the pythonfmu libraries' finalizers
    exit_process(main(default_out=Path(__file__).resolve().parent / "build"))
