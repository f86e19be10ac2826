"""Procedures 2-3: choose, at every step of a joint stream, the DK solution that is the robot.

``Tracker(model, map_tensor, mode=...)`` is constant (geometry, map, options);
its mutable data (previous pose and joints, the scale of recent joint steps, the
proof's tubes...) is one flat array that one compiled call packs, steps and
advances in place (:mod:`._kernels.stepper`); :attr:`state` is the same data as a
:class:`TrackerState`, made when read.  A rejected input leaves it untouched, and
a caller can save and restore it (:meth:`snapshot`, :meth:`restore`: an FMU
rolling back a step does exactly that).

Modes
-----
``mode="paper"``: procedures 2 and 3 exactly as written.  All six DK
solutions of the current joints, numbered by the map's rule; procedure 2 at the
previous pose (labels of the nodes within radius ``r``, eq. 18-19); far from
a border the region is the one label seen; near a border it is the label of the
node nearest the eq. 22 prediction ``X_prev - J^-1 K (q - q_prev)``; the
answer is the solution with that number.  Where that solution is not real
(procedure 3 has no answer) the nearest real solution to the prediction is
returned and the step is flagged ``ambiguous``.

``mode="default"``: what the measurements (README, ``bench/bench_tracker.py``)
show works best.  The eq. 22 predictor is a single Euler step of the velocity
model; near singularities and for coarse sampling its error is as large as the
distance between solutions.  The default mode integrates the same velocity
model ``J dX = -K dq`` along the straight joint segment from the previous to
the current joints with RK4 (one substep per 0.05 rad of joint motion, at most
16): a continuation predictor whose error is far below the gap between
solutions whenever the segment does not pass a branch point.  Candidates are
the real solutions whose label is seen by procedure 2 near the previous pose
or near the prediction (the map's part: a solution in a region not adjacent to
the motion is never taken); the one nearest the prediction wins.  The choice is
flagged ``ambiguous`` when it is not certain: the nearest other real solution
is less than ``1 / ambiguity_ratio`` times farther from the prediction, the map
and the prediction disagree, the predictor met a singularity (it then falls
back to eq. 22 or the previous pose), or the joint step is ``jump_factor``
times larger than recent steps.  ``ambiguous`` is a heuristic; ``certain`` is the proof.

Certainty
---------
Every step reports ``certain``: True only when the tracker has *proved* that
the returned pose lies on the branch continued from the start pose, through an
unbroken chain of certificates back to :meth:`reset` (the *honest start* below),
and ``pose_bound`` (m, m, rad): half-widths of a box about the returned pose that
holds the robot's pose.  A certificate is about a joint path between samples: the
straight segment between the previous and the current joints (or, for the
chains of boxes, the parabola through the last three samples where the segment
meets a singularity), widened by ``joint_tolerance`` for measured joints.

1. *tube* (:mod:`._kernels.tube`): the step's joint segment is covered by pieces,
   each a box of joints (the piece of the segment, widened by the tolerance); for
   each piece a parametric Krawczyk test proves that every joint vector of the box
   has exactly one solution in a *tube* that follows the needle of poses the box
   maps to (``x~ + S (q - q~) + y``, ``|y| <= rho``, ``S = -J^-1 K``).  Tubes whose
   boxes meet are proved to hold the same solution there, the first takes over
   from the previous step's tube, a last one covers the reading's own box: the
   robot's pose is that tube's solution, within ``pose_bound`` of the returned
   pose (``|S| tol + kappa``; about 1e-13 with exact joints).  A step far from
   singularities needs two or three tube tests.
2. *continuation*: a chain of Krawczyk boxes along the path from the single
   candidate, each box proved to hold exactly one solution for every joint value
   of its piece of the path, names the branch at the new joints;
3. *elimination*: otherwise every real solution of the new joints is followed
   back along the path; one whose chain provably ends at a non-candidate is
   dropped (two branches cannot meet without a singularity in between);
4. *posture*: when several remain, those whose elbows are not in the map's
   posture are dropped (the robot keeps its posture; ``posture_certificate``).

The tracker keeps a *candidate set*, the DK solutions the true branch can be, in
its state (:mod:`._kernels.candidates`; the chains of boxes:
:mod:`._kernels.certify`).  One candidate left means certain with exact joints;
the point's own tube then gives the bound.  With measured joints the chains of
2-4 follow the measured joints: they steer the choice (and make ``trust``
*possible*), and only tubes and re-acquisition vouch.  In default mode the
certificates also decide the answer: the one left, or the candidate nearest the
prediction; paper mode keeps procedure 3's answer and is certain only when it is
the candidate left.  Once a step is not certain, ``uncertain_since`` gives the
step index since which, until a certificate names the branch again; a chain of
boxes uses at most ``max_tests`` Krawczyk tests, a chain of tubes at most 400.
``trust`` sums it up for a controller: *certain* (act on the pose, within
``pose_bound``), *possible* (the branch along the measured joints is known, not
proved over the tolerance: a fold may lie within it), *lost*.  Measured on the
suites: ``bench/bench_tracker.py`` and ``bench/bench_sensors.py``.

An honest start
---------------
:meth:`reset` takes an approximate initial pose ``X0``, the robot within
``start_tolerance`` (m, m, rad) of it, and the initial joints.  It starts from
the DK solution of the joints in that start region and is certain when it proves
it the only pose the robot can be in (:mod:`solver.start`: the reading's tube, a
Krawczyk box about it, and a branch and bound over the start region in all eight
postures); otherwise it starts uncertain and :attr:`start` says why and what to
change.  With exact joints nothing else can make a later step certain; with
measured joints re-acquisition can.

Sensors
-------
The certificates above are about the joints the tracker is given.  Joints from
encoders are not the robot's: near a singularity a few milliradians of noise can
put the measured joints past a fold that the robot never crosses.  Give the
tracker a bound on the measurement error, ``joint_tolerance`` (rad, e.g. 3 noise
sigmas plus half an encoder step; :meth:`solver.sensors.Sensor.tolerance`), and
``certain`` means a proof for every joint path within that tolerance of the
samples: tubes cover the joint segment widened by the tolerance; once one fails
(a fold within the tolerance, or a box too wide for the test), *re-acquisition*
(:mod:`._kernels.reacquisition`) proves from the present sample alone, over the
poses the platform can have reached (``speed_bound``, m/s and rad/s: the hull
of a set-membership paving kept in ``TrackerState.paving``; else the tool
space), that one pose of the posture is the robot's.  The same region steers
the choice.  An *outlier gate* (``gate``, :mod:`._kernels.gates`) refuses a
sample whose unexpected joint motion moves the pose more than noise could
(status ``rejected``, state kept); a *speed gate* (with ``speed_bound``) holds
the pose when the chosen solution is farther than the platform can have moved
(status ``unreachable``, at most :data:`solver.tracker_state.MAX_HELD` samples);
``stuck_after`` detects a stuck joint (:mod:`solver.stuck`).  With
``joint_tolerance = 0``, joints on an encoder grid are taken as readings
(:mod:`solver.encoder_grid`).  The whole design, its measurements and what it
cannot do: ``docs/sensors.md``; the proofs hold while the sensor keeps its
tolerance.

The robot as built
------------------
The certificates are proofs about the model's geometry; no built robot has it exactly.  With
``geometry_tolerance`` (m: half-widths of the lengths and coordinates, from a description's
``[tolerance]``) they are proofs for every robot within it (:mod:`solver.as_built`): a built leg closes
within ``e_i`` of the model's (:mod:`solver.geometry_tolerance`), so a 3-RRR's certificates take each
leg's constraint within its slack ``sigma_i = e_i (2 l2_i + e_i)``, a 3-RPR's take ``joint_tolerance +
e_i``.  ``certain`` then means the branch is proved for all of them, and ``pose_bound`` encloses the
pose of each.  0 (the default) changes nothing.

A step budget
-------------
``step_budget`` (seconds) gives each :meth:`step` a deadline on the CPU's cycle counter
(:mod:`._kernels.clock`): every search of the step stops at it and the step returns its choice,
not certain, with ``out_of_budget``.  The tube chain's unfinished proof is a walk
(:mod:`._kernels.anytime`) kept in the state; the next steps continue it within their own
budgets, and the step whose walk reaches its own reading is certain (never back-dated).  Without
a budget every search runs to its test limits, as before.  Measured: ``bench/bench_budget.py``.

Every step reports a :class:`StepInfo`.
"""
from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np

from ._kernels import layout as _lay
from ._kernels.anytime import ANY_CUT, ANY_SIZE, walk_floats
from ._kernels.clock import cycles_per_second
from .checks import SolverInputError
from .grid import default_bounds
from .manipulator import Manipulator
from .maptensor import MapTensor
from .options import GATE, MAX_TESTS, REACQUIRE_BOXES, TrackerOptions
from .ordering import rule_code
from .as_built import as_built_pack, joint_width, reach_model
from .encoder_grid import encoder_bits, encoder_note, grid_tolerance
from .geometry_tolerance import geometry_tolerance as _geometry_tolerance
from .start import START_TOLERANCE, StartInfo, UncertainStartWarning, honest_start, start_tolerance_for
from .tracker_state import TrackerError
from .tracker_entry import CEntry
from .tracking import _TrackerBase

__all__ = ["Tracker", "TrackerOptions", "MAX_TESTS", "GATE", "REACQUIRE_BOXES", "START_TOLERANCE", "StartInfo"]

#: Default mode: joint motion per continuation substep (rad), and the most substeps of a step.
SUBSTEP_DQ, MAX_SUBSTEPS = 0.05, 16

#: With ``joint_tolerance = 0`` and a reset at joints off any encoder grid: the readings after it that are
#: checked for one (an encoder stream is on its grid from its first reading).
GRID_WATCH = 3



_TOOL_SPACE: dict = {}


def _tool_space(model: Manipulator) -> np.ndarray:
    """``default_bounds(model)`` (3, 2), computed once per geometry (it samples 7201 orientations)."""
    key = model.digest()
    if key not in _TOOL_SPACE:
        _TOOL_SPACE[key] = default_bounds(model)
    return _TOOL_SPACE[key]


class Tracker(CEntry, _TrackerBase):
    """The basic-regions DK tracker (procedures 2-3) of one posture.

    Parameters
    ----------
    model : Manipulator or RPRManipulator
    map_tensor : MapTensor
        Map of the tracker's posture, built for ``model`` (same geometry digest).
    mode : {"default", "paper"}
        See the module docstring.
    options : TrackerOptions, optional
        The options below as one checked object (:mod:`solver.options`); keywords given beside it
        replace its fields.  Without it the keywords make it.  Kept as :attr:`options` (what the tracker
        was given: :attr:`joint_tolerance` is the one in effect, which an encoder grid may set).
    r : float, optional
        Procedure-2 radius (eq. 18); default ``map_tensor.default_radius()``.
    weights : array_like (3,), optional
        Eq. 19 weights; default ``map_tensor.default_weights`` (1, 1, rho^2).
    ambiguity_ratio : float
        Default mode: flag ``ambiguous`` when ``d_best > ambiguity_ratio * d_second``.
    jump_factor : float
        Flag ``ambiguous`` when max|dq| exceeds this many times the recent mean step.
    singular_tol : float
        Hadamard ratio of J below which a configuration is reported singular.
    use_map : bool
        Default mode: restrict candidates by procedure 2 (True) or not (for measurements).
    posture_certificate : bool
        Let the posture certificate decide between candidates (the robot stays in
        the map's posture; see the module docstring).
    max_tests : int
        Krawczyk tests one chain of certificates may use.
    joint_tolerance : float
        Bound on the joints' measurement error, rad (0: the joints are exact).  See "Sensors".  Left
        at 0, a :meth:`reset` whose joints lie on an encoder grid (:func:`solver.encoder_grid.encoder_bits`)
        sets it to half an encoder step, with a warning and :attr:`StartInfo.note`; after a reset at
        exact joints, so does one of the first :data:`GRID_WATCH` readings on a grid (with a warning).
    gate : float
        Outlier gate (with ``joint_tolerance > 0``): refuse a sample whose joint step is off the
        expected one by more than the tolerance allows plus this many recent mean differences.
    speed_bound : (float, float) or None
        Bound on the platform's speed (m/s, rad/s) that narrows re-acquisition and the
        set-membership paving (needs ``dt``).  With measured joints and no bound, certainty lost
        near a singularity seldom comes back (see "Sensors").
    reacquire_boxes : int
        Pose boxes one re-acquisition may examine (0: none).
    stuck_after : int
        Identical readings in a row after which a joint is taken as stuck (0: never; for noisy
        encoders, :meth:`solver.sensors.Sensor.stuck_after`).  See :mod:`solver.stuck`.
    start_tolerance : array_like, shape (3,)
        How far (m, m, rad) the initial pose given to :meth:`reset` may be from the robot's: the
        tracker starts from the DK solution of the initial joints within it, certain when it is
        proved the only pose there (see "An honest start").  Default (None): :data:`START_TOLERANCE`
        scaled with the robot (:func:`solver.start.start_tolerance_for`; the paper's robot: as it is).
    step_budget : float or None
        Seconds one :meth:`step` may take (None: no budget, every search runs to its test
        limits).  When the budget runs out the step returns its choice, not certain, with
        ``out_of_budget``; the tube chain's unfinished proof goes on at the next steps (see "A
        step budget").  Measured overshoot: ``bench/bench_budget.py``.
    """

    def __init__(self, model: Manipulator, map_tensor: MapTensor, mode: str | None = None, *,
                 options: TrackerOptions | None = None, **kwargs):
        super().__init__(model)
        if mode is not None:
            kwargs["mode"] = mode
        if options is None:
            options = TrackerOptions(**kwargs)
        elif not isinstance(options, TrackerOptions):
            raise TrackerError(f"options: expected a TrackerOptions or None, got {type(options).__name__}")
        elif kwargs:
            options = replace(options, **kwargs)
        o = self.options = options
        try:
            self.geometry_tolerance = _geometry_tolerance(model, o.geometry_tolerance)
        except SolverInputError as exc:
            raise TrackerError(str(exc)) from None
        self.step_budget = o.step_budget
        if o.step_budget is not None:
            cycles_per_second()                 # calibrated now, not in the first step's budget
        self._anytime = np.zeros(ANY_SIZE)
        self.start_tolerance = np.array(start_tolerance_for(model) if o.start_tolerance is None
                                        else o.start_tolerance, dtype=float)
        if not isinstance(map_tensor, MapTensor):
            raise TrackerError(f"map_tensor: expected a MapTensor, got {type(map_tensor).__name__}")
        if map_tensor.model.digest() != model.digest():
            raise TrackerError(f"map_tensor: built for geometry {map_tensor.model.name!r}, not for "
                               f"{model.name!r}")
        self.joint_tolerance = o.joint_tolerance
        speed = (0.0, 0.0) if o.speed_bound is None else o.speed_bound
        self.speed_bound = o.speed_bound
        self.stuck_after = o.stuck_after
        # the robot as built (solver.as_built): a 3-RRR's legs carry a slack in the model pack, a 3-RPR's a
        # joint width on top of joint_tolerance; the tool space re-acquisition searches is that of legs
        # reaching that much farther (solver.as_built.reach_model)
        self._joint_width = joint_width(model, self.geometry_tolerance)
        self._model_pack = as_built_pack(model, self.geometry_tolerance, self._model_pack)
        bounds = np.array(_tool_space(reach_model(model, self.geometry_tolerance, o.joint_tolerance)), float)
        self.map = map_tensor
        self.mode = o.mode
        self.posture = map_tensor.posture
        self.name = f"tracker-{o.mode}" if o.use_map or o.mode == "paper" else "tracker-nomap"
        w = map_tensor.default_weights if o.weights is None else np.array(o.weights)
        r = map_tensor.default_radius(w) if o.r is None else o.r
        self._w = np.ascontiguousarray(w, dtype=float)
        self.r = r
        self._labels = np.array(map_tensor.labels, dtype=np.int8, order="C")   # writable: the kernels' one type
        self._map_pack = _lay.pack_map(map_tensor.origin, map_tensor.step, map_tensor.periodic, r * r, self._w)
        self._stencil = map_tensor._stencil(r, w)
        self._params = _lay.pack_tracker_params(o.ambiguity_ratio, o.jump_factor, SUBSTEP_DQ, MAX_SUBSTEPS,
                                                o.singular_tol, o.use_map, o.strategy, o.segment_singular,
                                                map_tensor.posture - 1 if o.posture_certificate else -1,
                                                o.max_tests, o.joint_tolerance + self._joint_width, o.gate,
                                                bounds[:2].ravel(), speed, o.reacquire_boxes)
        self._mode = _lay.MODE_PAPER if o.mode == "paper" else _lay.MODE_DEFAULT
        self._rule = rule_code(map_tensor.rule)
        self._entry_table()                     # the compiled step's C entry point (solver.tracker_entry)

    def reset(self, X0, q0, warn: bool = True) -> StartInfo:
        """Start tracking from an approximate configuration: the honest start.

        The tracker starts from the DK solution of ``q0`` within ``start_tolerance`` of ``X0``
        and is certain when it proves that solution the only pose the robot can be in (the
        robot within ``start_tolerance`` of ``X0``, its joints within ``joint_tolerance`` of
        ``q0``; :mod:`solver._kernels.start`).  Otherwise it starts uncertain from the DK
        solution nearest ``X0`` (or ``X0`` itself when ``q0`` has none) and says why.

        Parameters
        ----------
        X0 : array_like, shape (3,)
            The initial pose, known within ``start_tolerance`` (m, m, rad).
        q0 : array_like, shape (3,)
            The initial joints (rad), read within ``joint_tolerance``.
        warn : bool
            Warn (:class:`solver.start.UncertainStartWarning`) when the start is not proved, with the
            reason and the fix (a start known exactly, a homed robot: a small ``start_tolerance``, e.g.
            1 mm and 5 mrad; an approximate one: the tolerance it is known to).  False: only
            :attr:`StartInfo.reason` says it (the DK FMU logs it itself).

        Returns
        -------
        StartInfo
            Also kept as :attr:`start`.
        """
        super().reset(X0, q0)
        st = self.state
        note = self._encoder_tolerance(st.q)
        start = honest_start(self._model_pack, self.model, st.X, st.q, self.start_tolerance,
                             self.joint_tolerance + self._joint_width, self._w,
                             int(self._params[_lay.PARAM_REACQUIRE]) or REACQUIRE_BOXES)
        start = start._replace(note=note)
        self.start = start
        if warn and not start.certain:
            warnings.warn(UncertainStartWarning(f"{self.name}: certain is False until the tracker re-acquires: "
                                                f"{start.reason}"), stacklevel=2)
        self._watch = GRID_WATCH if self.joint_tolerance == 0.0 and self.model.kind == "3-RRR" else 0
        # the robot is within the proven bound of the start, or else within the start tolerance of X0 (the
        # start's own assumption): where re-acquisition and the set-membership steps begin
        anchor, bound = (start.X, start.pose_bound) if start.certain else (st.X, np.array(self.start_tolerance, float))
        self.state = replace(st, X=start.X.copy(), anchor=anchor.copy(), uncertain_since=-1 if start.certain else 0,
                             intact=start.certain, tube=start.tube, anchor_bound=bound.copy())
        return start

    def _encoder_tolerance(self, q0, what: str = "q0", stacklevel: int = 3) -> str:
        """With ``joint_tolerance = 0``: joints ``q0`` (3,) on an encoder grid are readings, not exact
        joints; take half an encoder step as the tolerance (so that ``certain`` is about the robot,
        not about the readings), say so (:func:`solver.encoder_grid.encoder_note`) and warn.  Returns the note
        ("" when nothing changed)."""
        if self.joint_tolerance > 0.0 or self.model.kind != "3-RRR":
            return ""
        bits = encoder_bits(q0)
        if bits is None:
            return ""
        tol = grid_tolerance(bits)
        self.joint_tolerance = tol
        self._params[_lay.PARAM_JOINT_TOL] = tol + self._joint_width
        note = encoder_note(what, bits, tol, self.speed_bound)
        warnings.warn(note, stacklevel=stacklevel)
        return note

    def _watch_grid(self, q):
        """After a reset at joints off any encoder grid, the first :data:`GRID_WATCH` readings: one on a
        grid makes the tracker take half a step as its tolerance from that step on, as a reset there
        would (the robot was homed at exact joints, the stream comes from encoders)."""
        self._watch -= 1
        if self._encoder_tolerance(q, f"the reading of step {self.state.steps + 1}", stacklevel=4):
            self._watch = 0

    def _walk(self):
        n = walk_floats(self._anytime)
        return self._anytime[:n].copy() if n else None

    def _out_of_budget(self):
        return self._anytime[ANY_CUT] > 0.0
