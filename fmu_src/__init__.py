"""FMI 2.0 Co-Simulation slaves of the project and the machinery to build and check them.

``fmu_src.table_slave``  runtime base class (a slave = a variable table + ``step``); it is bundled
                         into every FMU, so it imports nothing but the standard library and pythonfmu.
``fmu_src.fmi_build``    build-time and host-side tools: ``build_fmu`` (pythonfmu + post-processing of
                         modelDescription.xml + deterministic zip), ``validate``, ``simulate``,
                         ``run_libcosim``, ``write_osp_system_structure``, ``run_osp_system``.

This ``__init__`` stays import-free on purpose: it is also bundled into the FMUs, where fmpy and
libcosimpy need not exist.
"""
