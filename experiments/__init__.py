"""Experiments on the library: benchmark suites, stream simulators, figure scripts and oracles.

Nothing in :mod:`solver` imports this package, and an FMU carries none of it; the
benchmarks (``bench/``), the tests and the FMU build's reference runs do.  It imports
:mod:`solver` only (and matplotlib inside :mod:`experiments.figures`' functions).

Modules
-------
suite
    The tracker's trajectory benchmark: the paper circle, near-singular circles and the
    hard suite (all eight postures), with each path's difficulty.
sensors
    Measured joint streams: the library's encoder model (:class:`solver.sensors.Sensor`)
    with noise, quantization and glitches, the benchmark's sensor grades and the truth a
    stream is scored against.
figures
    The paper's Figs 13-18 (cross-sections of the basic regions, the circle experiment)
    and slices of a map tensor file, as PNG (``python -m experiments figures`` / ``plot``).
rpr_scan
    An independent reference DK of the 3-RPR (dense scan in phi, no polynomial) and Newton
    along a joint path.
rpr_cusps
    Cusps of the 3-RPR's singular curve and loops around them that change assembly mode.
rpr_suite
    The 3-RPR's trajectory benchmark, and the cusp loop of its FMU's reference run.
"""
