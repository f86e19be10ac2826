"""The closed loop of the paper's Fig. 2 (and the Fig. 3 scheme) run by an fmpy master: its scenario,
its wiring (defined once), the master and its results (see :mod:`cosim`)."""
