"""The compiled (numba) kernels of :mod:`solver`: private, called by the package's modules and, for the
kinematics core (:mod:`.kinematics`, :mod:`.linalg`), by the dynamics kernels.

Every kernel works on scalars and small arrays; arguments that travel together are packed
into flat float arrays whose fields are read through the named offsets of :mod:`.layout`
(never by position).  Modules:

- :mod:`.layout`: the packed arrays' offsets, the status / mode / rule codes, and the packers;
- :mod:`.linalg`: the one angle wrap and the one family of 3x3 algebra (determinant, Cramer
  solve, adjugate inverse, Hadamard ratio);
- :mod:`.kinematics`: the kinematics core: the one inverse kinematics, loop row, leg row
  (``J_q``'s denominator) and Jacobian (J and K, the Newton step on the loop constraints,
  the velocity model).  The dynamics kernels (:mod:`dynamics._kernels`) call this core and
  :mod:`.linalg`; they have no kinematics of their own;
- :mod:`.direct_kinematics`: all six DK solutions of one joint vector (the sextic);
- :mod:`.ordering`: the numbering rules of the six solutions;
- :mod:`.maptensor`: procedure 2 (labels near a pose) and the nearest node's label;
- :mod:`.krawczyk`, :mod:`.certify`: Krawczyk's test, and chains and tubes of its boxes;
- :mod:`.candidates`: the candidate set of a step (elimination of the other solutions, continuation);
- :mod:`.exclusion`: re-acquiring the branch from one sample (a branch and bound);
- :mod:`.gates`: the outlier and speed gates for measured joints;
- :mod:`.choice`: the predictor along the joint step and the nearest solution to a prediction;
- :mod:`.tracker_packs`: the named packs of a tracker step (the step's scratch and its result);
- :mod:`.scratch`: small working arrays in the calling kernel's stack frame, not on the heap (a step
  makes no heap allocation but the tube chain's table of pieces);
- :mod:`.clock`: the CPU's cycle counter, the step budget's deadline;
- :mod:`.anytime`: with a step budget, the tube chain as a walk the next steps continue;
- :mod:`.cache_stamp`: numba's cache stamped with the content of every kernel module;
- :mod:`.certified`: the certify phase of a step;
- :mod:`.tracker`, :mod:`.baselines`: one step of procedure 3, as phases (gate, solve, predict,
  choose, certify, speed gate, publish), and one step of each baseline.

All kernels are compiled on first use and cached by numba (next to their source in
``__pycache__``, or under ``$NUMBA_CACHE_DIR``).  :mod:`.cache_stamp` stamps the cache with the
content of every module here, not only the defining file's: a kernel's machine code holds the
kernels it calls and the packs' offsets from other files, so any change here recompiles every
kernel once.

The small helpers and phases that only other kernels call are ``@njit(cache=False)``: numba
compiles them with their first caller and links their machine code into every caller's cache
entry, so an entry of their own would only be compiled, written and shipped in the FMUs a second
time.  No kernel is
``inline="always"``: inlining at numba's level re-typed each callee in every caller and cost about
2 of the C entry point's 5 minutes of compile for under 1 % of a step's time (docs/benchmarks.md,
section first_run).
"""
import os as _os

from .cache_stamp import stamp_by_content as _stamp_by_content

_stamp_by_content(_os.path.dirname(_os.path.abspath(__file__)))
