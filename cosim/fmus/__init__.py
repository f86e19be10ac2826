"""Building the project's FMUs from the slaves in :mod:`fmu_src`: packaging, modelDescription.xml, the
native loader, checks, the reference runs and the ``python build_fmu.py`` command (see :mod:`cosim`)."""
