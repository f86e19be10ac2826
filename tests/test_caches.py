"""Every disk cache of the project lives under the one cache root (:func:`solver.cache_dir`).

The FMU runtime's kernel cache writes the rule out (it may not import :mod:`solver` before numba is
patched); this holds it to the library's rule under each way of setting the root.
"""
import pytest

from cosim.batch import fmu_files
from cosim.fmus import kernels
from dynamics.control import gains_cache_file
from fmu_src import kernel_cache
from solver import CACHE_ENV, cache_dir
from solver.mapcache import default_cache_dir


@pytest.mark.parametrize("setting", ["explicit", "xdg", "home"])
def test_every_cache_is_under_the_one_root(monkeypatch, tmp_path, setting):
    for name in (CACHE_ENV, "XDG_CACHE_HOME", "NUMBA_CACHE_DIR"):
        monkeypatch.delenv(name, raising=False)
    if setting == "explicit":
        monkeypatch.setenv(CACHE_ENV, str(tmp_path / "mine"))
        expected = tmp_path / "mine"
    elif setting == "xdg":
        monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
        expected = tmp_path / "xdg" / "rrr-dk"
    else:
        monkeypatch.setenv("HOME", str(tmp_path / "home"))
        expected = tmp_path / "home" / ".cache" / "rrr-dk"
    root = cache_dir()
    assert root == expected.resolve()
    assert default_cache_dir() == root / "maps"
    assert kernel_cache.cache_root() == root / "fmu-kernels"
    assert kernels.generic_root() == root / "fmu-kernels-generic"      # the kernels the build ships
    assert fmu_files.cache_root() == root / "fmus"
    assert gains_cache_file() == root / "designed-gains.json"


def test_numba_cache_dir_still_moves_the_kernel_cache_alone(monkeypatch, tmp_path):
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "root"))
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba"))
    assert kernel_cache.cache_root() == tmp_path / "numba"
    assert fmu_files.cache_root() == (tmp_path / "root").resolve() / "fmus"
