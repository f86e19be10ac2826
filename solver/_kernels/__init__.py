"""The compiled (numba) kernels of :mod:`solver`: private, called only by the package's modules.

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
- :mod:`.exclusion`: re-acquiring the branch from one sample (a branch and bound);
- :mod:`.gates`: the outlier and speed gates for measured joints;
- :mod:`.choice`: the predictor along the joint step and the nearest solution to a prediction;
- :mod:`.tracker`, :mod:`.baselines`: one step of procedure 3 and of each baseline.

All kernels are compiled on first use and cached by numba next to their source.
"""
