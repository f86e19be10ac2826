"""What an FMU carries at run time: the FMI 2.0 Co-Simulation slaves of the project and their runtime.

The slaves: ``RRRDirectKinematics`` (the tracker on the embedded map tensor), ``RPRDirectKinematics``
(the same for the 3-RPR), ``RRRPlant`` (the robot's dynamics) and ``ComputedTorqueController``, one
script, one readme (``<name>.md``) and one reference CSV (``reference/<name>.csv``) each; the C
source of the native loader every FMU's binary is built from (``loader/``).

The runtime, bundled into every FMU (standard library and pythonfmu only): ``table_slave`` (the base
class: a slave = a variable table + ``step``; the FMI adapter), ``variables`` (the table rows and
their FMI rules), ``fmi_states`` (the FMI state machine), ``slave_state`` (FMU state and rollback
snapshots), ``value_access`` / ``value_checks`` (fmi2Get/Set by value reference, and what a slave
checks before it trusts a value), ``kernel_cache`` (numba's cache for the bundled kernels, keyed by
the FMU's content), ``requirements`` (the packages the FMU needs from its host, checked first at
instantiation), ``dk_variables`` (the rows both DK FMUs share).

Import direction: the slaves and the runtime import only the runtime, :mod:`solver` and the math of
:mod:`dynamics`.  Building and running FMUs from outside is the host
package :mod:`cosim`, which imports this one and never the other way round.  This ``__init__``
stays import-free: it is bundled into the FMUs, where fmpy and libcosimpy need not exist.
"""
