"""FMI 2.0 Co-Simulation slaves of the project and the host-side machinery to build, check and run them.

The slaves: ``RRRDirectKinematics`` (the tracker on the embedded map tensor), ``RRRPlant`` (the
robot's dynamics) and ``ComputedTorqueController``, one script and one readme each.

The runtime, bundled into every FMU (standard library and pythonfmu only): ``table_slave`` (the base
class: a slave = a variable table + ``step``; the FMI adapter), ``variables`` (the table rows and
their FMI rules), ``slave_state`` (FMU state and rollback snapshots), ``value_access`` (fmi2Get/Set by
value reference), ``kernel_cache`` (numba's cache for the bundled kernels, keyed by the FMU's content),
``requirements`` (the packages the FMU needs from its host, checked first at instantiation).

The host side, never bundled: ``model_description`` (modelDescription.xml from the table),
``packaging`` (``build_fmu``: pythonfmu, only the modules the slave imports, deterministic zip),
``checks`` (``validate``, ``smoke_check``), ``unit`` (``FMUUnit``: the one FMU2Slave driver, and the
process rules of pythonfmu FMUs), ``simulation`` (``simulate``: fmpy.simulate_fmu that raises),
``libcosim`` (DNV libcosim runner, OSP system files), ``builds`` (the project's three FMUs,
``build_fmus``), ``references`` (their reference runs and CSVs), ``cli`` (``python build_fmu.py``).

Import direction: the slaves and the runtime import only the runtime, :mod:`solver` and the math of
:mod:`dynamics` (its public top-level names); the host side imports those, fmpy, pythonfmu and
libcosimpy.  Nothing here imports the co-simulation side (:mod:`dynamics.cosim`,
:mod:`dynamics.batch`), which imports the host side.  This ``__init__`` stays import-free: it is
also bundled into the FMUs, where fmpy and libcosimpy need not exist.
"""
