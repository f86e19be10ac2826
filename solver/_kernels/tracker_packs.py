"""The packs the phases of a tracker step read and write (:mod:`.tracker`), and the step pack.

A step is a sequence of phases (gate, solve, predict, choose, certify, speed gate,
publish), each a compiled function that reads and writes named fields of flat packs
and returns the few decisions it makes (the chosen solution, whether it is ambiguous...).
The packs, each a flat array whose fields are named by offsets (:mod:`.layout`):

* the constant inputs: the options ``params`` (``PARAM_*``), the model pack
  (``MODEL_*``, with ``sample_to_sextic``), the map pack (``MAP_*``, with the map's
  ``labels`` and the procedure-2 ``stencil``);
* the *state pack* (``state``, ``STATE_*``): what the step reads of the tracker's state,
  written by :meth:`solver.tracker_state.TrackerState.pack`;
* the *step pack* (``work``, ``STEP_*`` below, made by :func:`.tracker.step_pack`): what
  the phases derive from this step's joints (the joint step, the predictions), with the DK solutions ``poses`` (6, 3)
  complex / ``real`` (6,) and procedure 2 at the previous pose ``near_prev`` (7,);
* the *result pack* (``out_real``: ``OUT_*`` and ``F_*``; ``out_int``: ``I_*``), read back
  by :meth:`solver.tracker_state.TrackerState.after` and :meth:`solver.tracker_state.StepInfo.from_result`.

Flat packs, not namedtuples of arrays: numba reference-counts every array of a tuple
each time a phase receives it, which measured 20-25 % of a step.  A new phase reads
and writes fields by name; new per-step values get a ``STEP_*`` field.
"""
from __future__ import annotations

# ----------------------------------------------------------------------------- step pack
STEP_DQ = 0               # (3,) the joint step q - q_prev, angles wrapped, rad
STEP_QU = 3               # (3,) q unwrapped next to the previous joints, rad
STEP_X_LIN = 6            # (3,) eq. 22: the linear prediction at the previous pose
STEP_X_EXT = 9            # (3,) the tool-space extrapolation from the last two poses (default mode)
STEP_DQN = 12             # max|dq_i|, rad
STEP_JUMP = 13            # > 0: dqn is jump_factor times the recent mean step
STEP_SIZE = 14

