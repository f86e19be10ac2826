"""The named packs the phases of a tracker step read and write (:mod:`.tracker`).

A step is a sequence of phases (gate, solve, predict, choose, certify, speed gate,
publish), each a compiled function that takes the packs below and returns the few
decisions it makes (the chosen solution, whether it is ambiguous...):

* :data:`StepConfig`: what does not change between steps: the mode, the ordering
  rule, the options (``params``, :mod:`.layout` ``PARAM_*``), the model pack and its
  geometry views, the map's labels, grid and procedure-2 stencil;
* the *state pack* (``state``, :mod:`.layout` ``STATE_*``): what the step reads of the
  tracker's state, written by :meth:`solver.tracker_state.TrackerState.pack`;
* :data:`StepData`: this step's joints and what the phases compute from them (the
  joint step, the DK solutions, the predictions, procedure 2 at the previous pose);
* :data:`StepResult`: named views of the *result pack* (``out_real``, ``out_int``,
  :mod:`.layout` ``OUT_*``, ``F_*``, ``I_*``), read back by
  :meth:`solver.tracker_state.TrackerState.after`.

The packs are namedtuples (numba compiles them as plain structs, their arrays as
views): a phase names what it reads and writes, and a new phase adds a field.
"""
from __future__ import annotations

from collections import namedtuple

import numpy as np
from numba import njit

from .choice import joint_step
from .kinematics import geometry
from .layout import (INFO_F_SIZE, INFO_I_SIZE, MAP_ORIGIN, MAP_PERIODIC, MAP_R2, MAP_STEP, MAP_WEIGHTS, OUT_CANDS,
                     OUT_INFO, OUT_X, OUT_X_PRED, PARAM_JUMP, STATE_DQ_SCALE, STATE_EXT_SCALE, STATE_Q, STATE_X,
                     STATE_X2)

#: The constant inputs of a step: ``mode`` (MODE_*), ``rule`` (RULE_*), ``params`` (PARAM_SIZE,),
#: ``model_pack`` (MODEL_SIZE,) with its views ``M`` (3, 2), ``l1`` (3,), ``l2sq`` (3,), ``b`` (3, 2)
#: (m, m^2), ``sample_to_sextic`` (the DK constants), the map's ``labels`` (nx, ny, nphi),
#: ``origin`` (3,), ``step`` (3,), ``periodic``, squared procedure-2 radius ``r2``, eq. 19 weights
#: ``w`` (3,) and ``stencil`` (n, 3).
StepConfig = namedtuple("StepConfig", ("mode", "rule", "params", "model_pack", "M", "l1", "l2sq", "b",
                                       "sample_to_sextic", "labels", "origin", "step", "periodic", "r2", "w",
                                       "stencil"))

#: One step's data: the joints ``q`` (3,) rad; from the state pack the previous pose ``Xp`` (3,),
#: joints ``qp`` (3,) and the pose before ``X2`` (3,), the ratio of time steps ``ext_scale``; the
#: wrapped joint step ``dq`` (3,), its size ``dqn = max|dq_i|`` (rad), ``qu = qp + dq`` (q unwrapped
#: next to qp), ``jump`` (dqn is ``jump_factor`` times the recent mean step); filled by the phases:
#: the DK solutions ``poses`` (6, 3) complex and ``real`` (6,) (solve), procedure 2 at ``Xp``
#: ``near_prev`` (7,) (solve), the eq. 22 prediction ``X_lin`` (3,) and the tool-space
#: extrapolation ``X_ext`` (3,) (predict).
StepData = namedtuple("StepData", ("q", "Xp", "qp", "X2", "ext_scale", "dq", "dqn", "qu", "jump", "poses", "real",
                                   "near_prev", "X_lin", "X_ext"))

#: Named views of the result pack: the pose returned ``X`` (3,), the prediction ``X_pred`` (3,), the
#: float fields ``info_f`` (INFO_F_SIZE,: F_*), the integer fields ``info_i`` (INFO_I_SIZE,: I_*) and
#: the candidates after the step ``cands`` (6, 3).
StepResult = namedtuple("StepResult", ("X", "X_pred", "info_f", "info_i", "cands"))


@njit(cache=True)
def step_config(mode, rule, model_pack, sample_to_sextic, labels, map_pack, stencil, params):
    """The :data:`StepConfig` of the packed constant inputs (views, nothing copied)."""
    M, l1, l2sq, b = geometry(model_pack)
    return StepConfig(mode, rule, params, model_pack, M, l1, l2sq, b, sample_to_sextic, labels,
                      map_pack[MAP_ORIGIN:MAP_ORIGIN + 3], map_pack[MAP_STEP:MAP_STEP + 3],
                      map_pack[MAP_PERIODIC] > 0.0, map_pack[MAP_R2], map_pack[MAP_WEIGHTS:MAP_WEIGHTS + 3], stencil)


@njit(cache=True)
def step_data(q, state, params):
    """The :data:`StepData` of joints ``q`` (3,) from the state pack (the phases' arrays allocated)."""
    qp = state[STATE_Q:STATE_Q + 3]
    dq = np.empty(3)
    dqn = joint_step(q, qp, dq)
    qu = np.empty(3)                                   # q unwrapped next to the previous joints
    for i in range(3):
        qu[i] = qp[i] + dq[i]
    dq_scale = state[STATE_DQ_SCALE]
    jump = dq_scale > 0.0 and dqn > params[PARAM_JUMP] * dq_scale
    return StepData(q, state[STATE_X:STATE_X + 3], qp, state[STATE_X2:STATE_X2 + 3], state[STATE_EXT_SCALE], dq,
                    dqn, qu, jump, np.empty((6, 3), dtype=np.complex128), np.empty(6, dtype=np.bool_),
                    np.zeros(7, dtype=np.bool_), np.empty(3), np.empty(3))


@njit(cache=True)
def step_result(out_real, out_int):
    """The :data:`StepResult` views of the result pack, its info fields zeroed."""
    info_f, info_i = out_real[OUT_INFO:OUT_INFO + INFO_F_SIZE], out_int
    for i in range(INFO_I_SIZE):
        info_i[i] = 0
    for i in range(INFO_F_SIZE):
        info_f[i] = 0.0
    return StepResult(out_real[OUT_X:OUT_X + 3], out_real[OUT_X_PRED:OUT_X_PRED + 3], info_f, info_i,
                      out_real[OUT_CANDS:OUT_CANDS + 18].reshape((6, 3)))
