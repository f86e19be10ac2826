"""Where the FMUs' sources live: the slave scripts, their readmes and reference CSVs, the loader's C source.

They are files of the package :mod:`fmu_src` (what an FMU carries at run time); the host side finds
them here, once, and never by a path relative to its own modules.
"""
from __future__ import annotations

from pathlib import Path

import fmu_src

__all__ = ["SLAVE_DIR", "REFERENCE_DIR", "LOADER_SOURCE", "slave_script", "slave_readme"]

#: the folder of :mod:`fmu_src`: one ``<FMU name>.py`` slave script and one ``<FMU name>.md`` readme each
SLAVE_DIR = Path(fmu_src.__file__).resolve().parent
#: the reference CSVs (Reference-FMUs style), ``<FMU name>.csv``
REFERENCE_DIR = SLAVE_DIR / "reference"
#: the C source of the native loader every FMU's binary is built from
LOADER_SOURCE = SLAVE_DIR / "loader" / "fmi2_loader.c"


def slave_script(name: str) -> Path:
    """The slave script of FMU ``name``: ``fmu_src/<name>.py``."""
    return SLAVE_DIR / f"{name}.py"


def slave_readme(name: str) -> Path:
    """The readme of FMU ``name``: ``fmu_src/<name>.md``."""
    return SLAVE_DIR / f"{name}.md"
