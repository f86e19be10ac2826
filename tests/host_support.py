"""Shared by the tests of the FMUs in other hosts (test_ssp.py, test_hosts.py, test_exit.py).

* :func:`session_fmus`: the three FMUs (DK map 40 mm / 6 deg), built once per test session into the
  session's temporary folder (:func:`cosim.fmus.builds.build_fmus` reuses what is there).
* :func:`run_python`: a script in a child process (an FMU host of its own: the child loads the
  FMUs, not this process), with its exit status, stdout and stderr.
"""
from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np

from cosim.fmus.builds import build_fmus

#: the coarse map of the tests (fast to build; the tracker's answers do not depend on it)
RESOLUTION = (0.04, float(np.deg2rad(6.0)))
REPO = Path(__file__).resolve().parent.parent


def session_fmus(tmp_path_factory) -> dict:
    """{FMU name: path} of the three FMUs, built once per session (``<basetemp>/host-fmus``)."""
    return build_fmus(tmp_path_factory.getbasetemp() / "host-fmus", resolution=RESOLUTION, log=lambda *a: None)


def run_python(code: str, *args, python: str | Path = sys.executable, cwd: Path | None = None,
               timeout: float = 600) -> subprocess.CompletedProcess:
    """Run ``code`` (dedented) as a script with ``args`` in a child ``python``; never raises on its status."""
    return subprocess.run([str(python), "-c", textwrap.dedent(code), *map(str, args)], capture_output=True,
                          text=True, timeout=timeout, cwd=str(cwd or REPO))
