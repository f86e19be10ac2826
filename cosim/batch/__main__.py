"""``python -m cosim.batch``: see :mod:`cosim.batch.cli` and docs/batch.md."""
# the entry point lives in an importable module: dask pickles the functions of __main__ by value
from cosim.batch.cli import main_and_exit

if __name__ == "__main__":
    main_and_exit()
