"""Layout of every packed kernel argument, and the codes the kernels share with Python.

numba unboxes each argument of a call from Python separately, so the per-step kernels take
few arguments: values that travel together are packed into one flat float64 array.  Each
field of a packed array is read and written through the offsets below (module-level
integer constants, which numba compiles as literals); a field of several values spans
``[OFFSET, OFFSET + n)``.  The ``pack_*`` functions build the arrays on the Python side.
"""
from __future__ import annotations

import numpy as np

# ----------------------------------------------------------------------------- model pack
# The geometry and the DK constants of one manipulator (built once per model).
MODEL_MOTORS = 0          # (3, 2) motor positions M_i, m
MODEL_L1 = 6              # (3,) proximal lengths l1_i, m
MODEL_L2SQ = 9            # (3,) squared distal lengths l2_i^2, m^2
MODEL_OFFSET = 12         # (3,) the legs' offset bounds e_i of the robot as built, m (0: the model is the robot)
MODEL_PLATFORM = 15       # (3, 2) platform joints b_i in the platform frame, m
MODEL_COS8 = 21           # (8,) cos of the eight sample angles 2 pi m / 8
MODEL_SIN8 = 29           # (8,) sin of the eight sample angles
MODEL_PSI = 37            # (8,) half-angle shift psi_j of each sample j
MODEL_SNAP_TOL = 45       # |Im phi| below which a root is tried as real
MODEL_REAL_TOL = 46       # residual below which a polished root is real, m^2
MODEL_NEWTON_STEPS = 47   # Newton steps that polish a real root (an integer)
MODEL_SIZE = 48
#: Every leg is a circle constraint |P + R(phi) b_i - D_i|^2 = r_i^2: for the 3-RRR the joint moves the
#: centre (D_i = M_i + l1_i (cos q_i, sin q_i), r_i^2 = MODEL_L2SQ), for the 3-RPR the radius (l1 = 0 so
#: D_i = M_i, the base joint; MODEL_L2SQ < 0 marks the leg prismatic: r_i = q_i, kinematics.radius_sq).
#: MODEL_OFFSET follows MODEL_L2SQ: kinematics.geometry hands both to the kernels as one (6,) view, the
#: squared radii and the offsets (a revolute leg of a robot as built closes within e_i of the model's:
#: |P + R(phi) b_i - D_i|^2 within sigma_i = e_i (2 l2_i + e_i) of l2_i^2; kinematics.leg_slack).

# ----------------------------------------------------------------------------- tracker state pack
# What a step reads of the tracker's state (rewritten before every step).
STATE_X = 0               # (3,) previous pose
STATE_Q = 3               # (3,) previous joints
STATE_X2 = 6              # (3,) the pose before the previous one (= STATE_X right after a reset)
STATE_HISTORY = 9         # consecutive known poses, 1 or 2
STATE_DQ_SCALE = 10       # running mean of recent joint step sizes, rad (0: none yet)
STATE_EXT_SCALE = 11      # ratio of this time step to the previous one (tool-space extrapolation)
STATE_Q2 = 12             # (3,) the joints before the previous ones (the parabola of the certificates)
STATE_HAVE_Q2 = 15        # > 0 when STATE_Q2 holds them
STATE_N_CAND = 16         # number of certificate candidates (1: the branch is known)
STATE_VERIFIED = 17       # > 0: the single candidate ends a verified chain (its tiny box is proved)
STATE_CANDS = 18          # (6, 3) the candidates: the DK solutions the true branch can be
STATE_INTACT = 36         # > 0: every step since the reset was vouched for over the joint tolerance tube
                          # (always, with exact joints)
STATE_A_SCALE = 37        # envelope of recent joint innovations max|dq - expected dq|, rad (the gate's scale)
STATE_REFUSED = 38        # samples refused in a row since the last accepted one
STATE_ANCHOR = 39         # (3,) the pose of the last certain step (re-acquisition's region)
STATE_ANCHOR_AGE = 42     # seconds from that step to this one (NaN: unknown)
STATE_STEP_DT = 43        # seconds from the last accepted sample to this one (NaN: unknown)
STATE_ANCHOR_BOUND = 44   # (3,) the pose bound at STATE_ANCHOR (m, m, rad; inf: none, e.g. an unproved start)
STATE_N_TUBES = 47        # tubes in STATE_TUBE; > 0: the last step was certain and they hold the robot's pose
STATE_TUBE = 48           # (27, 36) the last step's cover (:mod:`.tube`: MAX_COVER tubes of TUBE_SIZE)
#: Boxes of the set-membership paving (:mod:`.paving`): the pose set the robot is in, box by box.
PAVE_BOXES = 32
STATE_N_PAVE = 48 + 27 * 36  # boxes in STATE_PAVE (0: the box about STATE_ANCHOR alone)
STATE_PAVE = STATE_N_PAVE + 1  # (PAVE_BOXES, 6) pose boxes (x, y, phi lo/hi) holding the robot at STATE_ANCHOR_AGE ago
STATE_SIZE = STATE_PAVE + 6 * PAVE_BOXES

# ----------------------------------------------------------------------------- map pack
# The grid of a map tensor and the procedure-2 neighbourhood (eq. 18-19).
MAP_ORIGIN = 0            # (3,) coordinates of node (0, 0, 0)
MAP_STEP = 3              # (3,) node spacing
MAP_PERIODIC = 6          # > 0 when the phi axis wraps around
MAP_R2 = 7                # squared procedure-2 radius
MAP_WEIGHTS = 8           # (3,) eq. 19 weights
MAP_SIZE = 11

# ----------------------------------------------------------------------------- tracker options
PARAM_AMBIGUITY = 0       # ambiguous when d_best > this * d_second
PARAM_JUMP = 1            # a jump when max|dq| > this * the recent mean step
PARAM_SUBSTEP_DQ = 2      # joint motion per continuation substep, rad
PARAM_MAX_SUBSTEPS = 3    # at most this many continuation substeps
PARAM_SINGULAR = 4        # Hadamard ratio of J below which a configuration is singular
PARAM_USE_MAP = 5         # > 0: restrict candidates by procedure 2
PARAM_STRATEGY = 6        # one of the STRATEGY_* codes
PARAM_SEGMENT_SINGULAR = 7  # STRATEGY_SEGMENT: a segment this close to singular trusts extrapolation
PARAM_POSTURE_BITS = 8    # posture - 1 for the posture certificate, -1 without it
PARAM_MAX_TESTS = 9       # Krawczyk tests one chain may use
PARAM_JOINT_TOL = 10      # bound on the joints' measurement error, rad (0: exact joints)
PARAM_GATE = 11           # outlier gate: refuse a joint step this many times beyond the expected one
PARAM_ROOT = 12           # (4,) x lo/hi, y lo/hi of the tool space, m
PARAM_SPEED = 16          # (2,) bound on the platform's speed, m/s and rad/s (0: none)
PARAM_REACQUIRE = 18      # pose boxes a re-acquisition may examine (0: no re-acquisition)
PARAM_SIZE = 19

# ----------------------------------------------------------------------------- baseline options
BASELINE_WEIGHTS = 0      # (3,) eq. 19 weights
BASELINE_TOL = 3          # Newton / CLDK stop at this residual max|F_i|, m^2
BASELINE_SEPARATION = 4   # Newton with a separation flag: certain when d_other > this * d_step
BASELINE_SIZE = 5

# ----------------------------------------------------------------------------- step outputs
# Float outputs of a step: the pose, the prediction, then the float info fields.
OUT_X = 0                 # (3,) the pose returned
OUT_X_PRED = 3            # (3,) the prediction it was compared with
OUT_INFO = 6              # (INFO_F_SIZE,) the fields F_*
OUT_CANDS = 12            # (6, 3) the candidates after the step (as STATE_CANDS)
OUT_BOUND = 30            # (3,) the pose bound's half-widths (m, m, rad); inf when not certain
OUT_N_TUBES = 33          # tubes in OUT_TUBE (when certain)
OUT_TUBE = 34             # (27, 36) the step's cover (:mod:`.tube`) when certain
OUT_REGION = 34 + 27 * 36  # (6,) when not certain: a pose box holding the robot (x, y, phi lo/hi), NaN when none
OUT_N_PAVE = OUT_REGION + 6  # boxes in OUT_PAVE (0 when OUT_REGION is NaN)
OUT_PAVE = OUT_N_PAVE + 1    # (PAVE_BOXES, 6) when not certain: the paving whose hull is OUT_REGION
OUT_SIZE = OUT_PAVE + 6 * PAVE_BOXES
# float info fields (offsets inside OUT_INFO)
F_D_BEST, F_D_SECOND, F_COND_PREV, F_COND, F_DQ, F_INNOV = 0, 1, 2, 3, 4, 5
INFO_F_SIZE = 6
# integer outputs of a step
I_LABEL, I_NEAR_BORDER, I_N_REAL, I_AMBIGUOUS, I_STATUS, I_JUMP, I_REGION = 0, 1, 2, 3, 4, 5, 6
I_CERTAIN, I_CERTIFICATE, I_N_CAND, I_INTACT, I_TRUST = 7, 8, 9, 10, 11
INFO_I_SIZE = 12

# ----------------------------------------------------------------------------- a stream's results
# What the compiled stream loop of ``track`` writes at step k of an n-step stream (:func:`.stepper.record`),
# straight into the arrays :class:`solver.TrackResult` returns (views of three blocks):
# a float block (TRACK_FLOATS * n,): the pose (n, 3) from TF_X * n, the prediction (n, 3) from TF_X_PRED * n,
# the pose bound (n, 3) from TF_BOUND * n, then cond, d_best, d_second and the step's seconds, (n,) each;
TF_X, TF_X_PRED, TF_BOUND, TF_COND, TF_D_BEST, TF_D_SECOND, TF_SECONDS = 0, 3, 6, 9, 10, 11, 12
TRACK_FLOATS = 13
# an int64 block (TRACK_INTS, n), one row a field;
TI_LABEL, TI_N_REAL, TI_STATUS, TI_CERTIFICATE, TI_N_CAND, TI_SINCE, TI_TRUST = 0, 1, 2, 3, 4, 5, 6
TRACK_INTS = 7
# a bool block (TRACK_BOOLS, n), one row a field.
TB_NEAR_BORDER, TB_AMBIGUOUS, TB_JUMP, TB_CERTAIN, TB_OUT_OF_BUDGET = 0, 1, 2, 3, 4
TRACK_BOOLS = 5

# ----------------------------------------------------------------------------- codes
#: Status of a step (also the DK FMU's ``status`` output); REJECTED: a sample the tracker (outlier
#: gate) or the FMU (input check) refused, the pose held.
STATUS_OK, STATUS_UNREACHABLE, STATUS_SINGULAR, STATUS_REJECTED, STATUS_DIVERGED = 0, 1, 2, 3, 4
#: The status codes by name, the one table of them.
STATUS = {STATUS_OK: "ok", STATUS_UNREACHABLE: "unreachable", STATUS_SINGULAR: "singular",
          STATUS_REJECTED: "rejected", STATUS_DIVERGED: "diverged"}
#: Samples refused in a row after which the next one is taken anyway (the joints moved: certainty lost).
MAX_REFUSED = 2
#: What a controller can act on (``StepInfo.trust``): LOST, nothing proved about the branch; POSSIBLE, the
#: branch along the measured joints is known but not proved over the joint tolerance (a fold may lie
#: within it); CERTAIN, proved, the pose within ``pose_bound``.
TRUST_LOST, TRUST_POSSIBLE, TRUST_CERTAIN = 0, 1, 2
#: The trust levels by name, the one table of them.
TRUST = {TRUST_LOST: "lost", TRUST_POSSIBLE: "possible", TRUST_CERTAIN: "certain"}
#: Tracker modes.
MODE_PAPER, MODE_DEFAULT = 0, 1
#: Default-mode strategies: continuation only, extrapolation only, arbitrated by the segment's
#: closeness to a singularity, arbitrated by which predictor is more decisive.
STRATEGY_CONTINUATION, STRATEGY_EXTRAPOLATION, STRATEGY_SEGMENT, STRATEGY_DECISIVE = 0, 1, 2, 3
#: Baselines.
BASELINE_NEWTON, BASELINE_PREDICTOR_NEWTON, BASELINE_CLDK, BASELINE_NEAREST, BASELINE_NEWTON_SEPARATION = 0, 1, 2, 3, 4
#: Ordering rules (names in :data:`solver.ordering.ORDERING_RULES`).
RULE_REAL_PHI, RULE_LITERAL, RULE_REAL_X, RULE_REAL_Y, RULE_ASPECT = 0, 1, 2, 3, 4


# ----------------------------------------------------------------------------- packers
def pack_model(motors, l1, l2sq, platform, cos8, sin8, psi, snap_tol, real_tol, newton_steps,
               offset=(0.0, 0.0, 0.0)) -> np.ndarray:
    """The model pack (MODEL_SIZE,) of a geometry and its DK constants; ``offset`` (3,), m: the legs'
    offset bounds of the robot as built (:meth:`solver.geometry_tolerance.GeometryTolerance.offset_bound`)."""
    pack = np.empty(MODEL_SIZE)
    pack[MODEL_MOTORS:MODEL_MOTORS + 6] = np.ravel(motors)
    pack[MODEL_L1:MODEL_L1 + 3] = l1
    pack[MODEL_L2SQ:MODEL_L2SQ + 3] = l2sq
    pack[MODEL_OFFSET:MODEL_OFFSET + 3] = offset
    pack[MODEL_PLATFORM:MODEL_PLATFORM + 6] = np.ravel(platform)
    pack[MODEL_COS8:MODEL_COS8 + 8] = cos8
    pack[MODEL_SIN8:MODEL_SIN8 + 8] = sin8
    pack[MODEL_PSI:MODEL_PSI + 8] = psi
    pack[MODEL_SNAP_TOL] = snap_tol
    pack[MODEL_REAL_TOL] = real_tol
    pack[MODEL_NEWTON_STEPS] = float(newton_steps)
    return pack


def pack_map(origin, step, periodic: bool, r2: float, weights) -> np.ndarray:
    """The map pack (MAP_SIZE,) of a map tensor's grid and a procedure-2 neighbourhood."""
    pack = np.empty(MAP_SIZE)
    pack[MAP_ORIGIN:MAP_ORIGIN + 3] = origin
    pack[MAP_STEP:MAP_STEP + 3] = step
    pack[MAP_PERIODIC] = 1.0 if periodic else 0.0
    pack[MAP_R2] = r2
    pack[MAP_WEIGHTS:MAP_WEIGHTS + 3] = weights
    return pack


def pack_tracker_params(ambiguity, jump, substep_dq, max_substeps, singular, use_map: bool, strategy: int,
                        segment_singular, posture_bits: int, max_tests: int, joint_tol: float = 0.0,
                        gate: float = 0.0, root=(0.0, 0.0, 0.0, 0.0), speed=(0.0, 0.0),
                        reacquire_boxes: int = 0) -> np.ndarray:
    """The tracker options (PARAM_SIZE,)."""
    pack = np.empty(PARAM_SIZE)
    pack[PARAM_AMBIGUITY] = ambiguity
    pack[PARAM_JUMP] = jump
    pack[PARAM_SUBSTEP_DQ] = substep_dq
    pack[PARAM_MAX_SUBSTEPS] = max_substeps
    pack[PARAM_SINGULAR] = singular
    pack[PARAM_USE_MAP] = 1.0 if use_map else 0.0
    pack[PARAM_STRATEGY] = float(strategy)
    pack[PARAM_SEGMENT_SINGULAR] = segment_singular
    pack[PARAM_POSTURE_BITS] = float(posture_bits)
    pack[PARAM_MAX_TESTS] = float(max_tests)
    pack[PARAM_JOINT_TOL] = joint_tol
    pack[PARAM_GATE] = gate
    pack[PARAM_ROOT:PARAM_ROOT + 4] = root
    pack[PARAM_SPEED:PARAM_SPEED + 2] = speed
    pack[PARAM_REACQUIRE] = float(reacquire_boxes)
    return pack


def pack_baseline_params(weights, tol, separation=3.0) -> np.ndarray:
    """The baseline options (BASELINE_SIZE,)."""
    pack = np.empty(BASELINE_SIZE)
    pack[BASELINE_WEIGHTS:BASELINE_WEIGHTS + 3] = weights
    pack[BASELINE_TOL] = tol
    pack[BASELINE_SEPARATION] = separation
    return pack
