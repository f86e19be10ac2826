"""Other co-simulation hosts: DNV libcosim (OSP system structures), SSP 1.0 packages (Ecos, libcosim,
OMSimulator), and the closed loop written as their system files (see :mod:`cosim`)."""
