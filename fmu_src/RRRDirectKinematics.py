"""RRRDirectKinematics: direct kinematics of the planar 3-RRR with basic regions, FMI 2.0 Co-Simulation.

Joint angles (q1, q2, q3) in, platform pose (x, y, phi) out: ``solver.Tracker`` (procedures 2-3 of
the paper) on the map tensor(s) (procedure 1) embedded in ``resources/maps/``.  Variables,
equations, initialization, status codes and bad-input behaviour: ``fmu_src/RRRDirectKinematics.md``
(also ``documentation/index.md`` inside the FMU).  Built by ``python build_fmu.py``.

Module-level code: imports, two build constants (rewritten by build_fmu.py in the staged copy), a
helper and the class (pythonfmu's C wrapper re-executes this module at every instantiation).
"""
# first: a host without the packages this FMU imports learns which and how to install them
# (fmu_src.requirements; the list is resources/requirements.txt)
from fmu_src.requirements import require
from fmu_src.wrapper_refs import hold_globals

hold_globals(globals())   # pythonfmu's wrapper releases a reference to this module's globals per instantiation
require(__file__)

import math
from pathlib import Path

import numpy as np
from pythonfmu import DefaultExperiment
from pythonfmu.enums import Fmi2Status

from fmu_src.dk_variables import NO_BOUND, dk_outputs, initial_pose, sensor_parameters
from fmu_src.table_slave import TableSlave, Var
from fmu_src.dk_lane import DKLane  # noqa: I001 - after table_slave (it installs the kernel cache)
from fmu_src.dk_maps import load_maps
from solver import (HOME_POSE, START_TOLERANCE, STATUS, Manipulator, Tracker, TrackerState, dk_all,
                    ik, jacobians, wrap_angle)
from solver._kernels.clock import cycles_per_second
from solver.geometry_tolerance import geometry_tolerance
from solver.tracker_state import TRUST
TRUST_CERTAIN, TRUST_LOST = (next(k for k, v in TRUST.items() if v == name) for name in ("certain", "lost"))

# Build constants: start values of the parameters ``posture`` and ``mode`` (build_fmu.py --posture/--mode)
# and the robot (build_fmu.py --robot: name, description digest, geometry as Manipulator.to_dict(), the
# start pose in BUILD_POSTURE; None: the paper's robot at HOME_POSE).  The tracker's model is the one
# the embedded maps carry; these give the start values and the description only.
BUILD_POSTURE = 1
BUILD_MODE = "default"
BUILD_ROBOT = None


def _build_robot():
    """The model and start pose (x, y in m, phi in rad) of this build's robot."""
    if BUILD_ROBOT is None:
        return Manipulator.paper(), tuple(float(v) for v in HOME_POSE)
    return Manipulator.from_dict(BUILD_ROBOT["geometry"]), tuple(float(v) for v in BUILD_ROBOT["start"])


_ROBOT, _START = _build_robot()
# the start tolerance's start values: the tracker's default, or a robot's scaled with its size
_START_TOLERANCE = tuple(BUILD_ROBOT.get("start_tolerance", START_TOLERANCE)) if BUILD_ROBOT else START_TOLERANCE
_GEOMETRY_TOLERANCE = float(BUILD_ROBOT.get("geometry_tolerance", 0.0)) if BUILD_ROBOT else 0.0
_ABOUT = ("the paper's 3-RRR (Table 1)" if BUILD_ROBOT is None else
          f"the 3-RRR {BUILD_ROBOT['name']!r} (robot description sha256 {BUILD_ROBOT['digest']})")


def _home_joints(posture):
    """Joints of the start pose in ``posture`` (start values of q1..q3, consistent with x0, y0, phi0)."""
    q = ik(_ROBOT, np.array(_START, dtype=float), posture)
    return [float(v) for v in q]


class RRRDirectKinematics(DKLane, TableSlave):
    """Direct kinematics of a 3-RRR (the paper's Table 1, or the robot of the build) by the basic-regions tracker."""

    description = ("Direct kinematics of the planar 3-RRR parallel manipulator with basic regions: "
                   f"joint angles -> platform pose (tracker + embedded map tensor); robot: {_ABOUT}")
    author = "rrr-dk"
    version = "0.1.0"
    license = "MIT"
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=1.0, step_size=1e-3)

    MODES = ("default", "paper")                 # value of the Integer parameter ``mode``
    JOINTS = ("q1", "q2", "q3")                   # the joint inputs (a subclass may rename them)
    MAP_DIR = "maps"                              # resources/maps/manifest.json + one .npz per posture
    Q0_TOL = 1e-6                                 # rad: q inputs at initialization "consistent" with X0
    _HOME_Q = _home_joints(BUILD_POSTURE)

    VARIABLES = (
        Var("q1", "Real", "input", start=_HOME_Q[0], unit="rad",
            description="motor angle theta_1 of leg 1 (from +x)"),
        Var("q2", "Real", "input", start=_HOME_Q[1], unit="rad",
            description="motor angle theta_2 of leg 2 (from +x)"),
        Var("q3", "Real", "input", start=_HOME_Q[2], unit="rad",
            description="motor angle theta_3 of leg 3 (from +x)"),
        *initial_pose(_START),
        Var("posture", "Integer", "parameter", "fixed", start=BUILD_POSTURE, min=1, max=8,
            description="IK branch 1..8 (CONVENTIONS.md); needs an embedded map of that posture"),
        Var("mode", "Integer", "parameter", "fixed", start=MODES.index(BUILD_MODE), min=0, max=1,
            description="tracker mode: 0 default (RK4 continuation + map), 1 paper (procedures 2-3 as written)"),
        *sensor_parameters("rad"),
        *dk_outputs(("q1", "q2", "q3"), start_tolerance=_START_TOLERANCE, geometry_tolerance=_GEOMETRY_TOLERANCE),
    )
    # _track: the tracker's snapshot (Tracker.snapshot: its whole mutable data, a read-only flat array or
    # a TrackerState: previous pose and joints, the pose before, the joint-step scale, the step count); _committed: (q, outputs) of the last doStep (or of
    # the initialization), what the outputs are whenever the inputs equal that q; _episode: status of the
    # last logged change (unreachable / singular episodes are logged once, at their start and end);
    # _since: (tracker step index, time) of the step since which the tracker cannot vouch, None while
    # it can (the time is that step's communication point, t + dt of its doStep)
    STATE = ("_track", "_committed", "_episode", "_since")
    # _maps/_model: read and verified at instantiation; _tracker: built at initialization for
    # (posture, mode), rebuilt by set_state if a state of other parameters is set; _cache: the last
    # tentative step, keyed by the q and the snapshot object it started from (never stale); _lane,
    # _lane_io: the loader's fast lane (fmu_src.dk_lane), made once per instance
    CONSTANT = ("_maps", "_model", "_tracker", "_cache", "_lane", "_lane_io")
    # a doStep's rollback keeps references: every STATE value is replaced, never changed in place
    # (a snapshot is read-only, a TrackerState frozen; the others are tuples and ints)
    IMMUTABLE_STATE = True
    # step() publishes the outputs of the joints it stepped to, the current inputs
    EVALUATE_AFTER_STEP = False
    SINGULAR_TOL = 1e-4                           # cond below this: status 2 (the tracker's default)

    # ------------------------------------------------------------------ instantiation
    def setup(self):
        try:
            self._maps, self._model = load_maps(Path(self.resources) / self.MAP_DIR, type(self).__name__)
        except Exception as exc:
            # instantiation fails (fmi2Instantiate returns NULL; pythonfmu logs the exception with status
            # fmi2Fatal when loggingOn): say why on Python logging too, fmpy.simulate_fmu shows no log
            self._pylog.error("instance %r: instantiation failed: %s", self.instance_name, exc)
            raise
        self._tracker = None
        self._track = None
        self._committed = None
        self._episode = 0
        self._since = None
        self._cache = None

    def _sensor_options(self):
        """(joint_tolerance, speed_bound, stuck_after) of the parameters, checked."""
        tol, v, w = self.joint_tolerance, self.speed_bound_linear, self.speed_bound_angular
        for name, value in (("joint_tolerance", tol), ("speed_bound_linear", v), ("speed_bound_angular", w)):
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"parameter {name!r} = {value!r}: expected a finite number >= 0")
        if (v > 0.0) != (w > 0.0):
            raise ValueError(f"parameters 'speed_bound_linear' = {v!r} and 'speed_bound_angular' = {w!r}: "
                             "expected both > 0 (a speed bound) or both 0 (none)")
        stuck = self.stuck_after
        if not (isinstance(stuck, int) and (stuck == 0 or stuck >= 2)):
            raise ValueError(f"parameter 'stuck_after' = {stuck!r}: expected 0 (off) or an integer >= 2")
        return float(tol), ((float(v), float(w)) if v > 0.0 else None), int(stuck)

    def _start_tolerance(self):
        """(m, m, rad) of the parameters ``start_tolerance_linear``, ``start_tolerance_angular``, checked."""
        lin, ang = self.start_tolerance_linear, self.start_tolerance_angular
        for name, value, unit in (("start_tolerance_linear", lin, "m"), ("start_tolerance_angular", ang, "rad")):
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"parameter {name!r} = {value!r}: expected a finite number > 0 ({unit}): how far "
                                 "the initial pose (x0, y0, phi0) may be from the robot's")
        return (float(lin), float(lin), float(ang))

    def _options(self):
        """The tracker options of the parameters (checked): what a tracker built for them has."""
        share = self.step_budget_share
        if not (math.isfinite(share) and 0.0 <= share <= 1.0):
            raise ValueError(f"parameter 'step_budget_share' = {share!r}: expected a number in [0, 1] (0: no budget)")
        geometry = geometry_tolerance(self._model, self.geometry_tolerance, "parameter 'geometry_tolerance'")
        return (*self._sensor_options(), self._start_tolerance(), geometry)

    def _make_tracker(self, posture, mode):
        if posture not in self._maps:
            raise ValueError(f"parameter 'posture' = {posture!r}: this FMU embeds maps of posture(s) "
                             f"{sorted(self._maps)} only (build_fmu.py --posture)")
        if not 0 <= mode < len(self.MODES):
            raise ValueError(f"parameter 'mode' = {mode!r}: expected 0 (default) or 1 (paper)")
        tol, speed, stuck, start_tol, geometry = self._options()
        if self.step_budget_share > 0.0:
            cycles_per_second()                   # the budget's clock calibrated now, not in the first doStep
        return Tracker(self._model, self._maps[posture], mode=self.MODES[mode], singular_tol=self.SINGULAR_TOL,
                       joint_tolerance=tol, speed_bound=speed, stuck_after=stuck, start_tolerance=start_tol,
                       geometry_tolerance=geometry)

    # ------------------------------------------------------------------ initialization
    def on_initialized(self):
        """Reset the tracker at (x0, y0, phi0) with the joints at t0 (see the readme, "Initialization")."""
        try:
            self._initialize_tracker()
        except Exception:
            self.status = 3                       # every doStep will be refused with the reason
            raise

    def _init_failed(self, reason):
        # a refused initialization (state error): the outputs say so too
        self.status = 3
        super()._init_failed(reason)

    def _initialize_tracker(self):
        self._tracker, q0 = self._start(log=True)
        self._track = self._tracker.snapshot()
        self._cache = None
        self._initial_outputs(self._tracker, log=True)
        self._committed = (tuple(float(v) for v in q0), self._outputs())
        self._dk_lane_connect()                      # behind the C loader: the hot calls without Python

    def _start(self, log):
        """A tracker for the parameters, reset by its honest start (see the readme, "Initialization"):
        ``(tracker, q0)``; raises ValueError on a refused parameter or initial pose."""
        tracker = self._make_tracker(self.posture, self.mode)
        X0 = np.array([self.x0, self.y0, self.phi0], dtype=float)
        for name, value in zip(("x0", "y0", "phi0"), X0):
            if not math.isfinite(value):
                raise ValueError(f"parameter {name!r} = {value!r} is not finite")
        q_ik = ik(self._model, X0, self.posture)
        if np.isnan(q_ik[0]):
            raise ValueError(f"the initial pose (x0, y0, phi0) = ({X0[0]!r}, {X0[1]!r}, {X0[2]!r}) is outside "
                             f"the tool space of posture {self.posture} (no inverse-kinematics solution)")
        q_in = np.array(self._joints(), dtype=float)
        finite = bool(np.all(np.isfinite(q_in)))
        gap = float(np.max(np.abs(wrap_angle(q_in - q_ik)))) if finite else math.inf
        if gap <= self.Q0_TOL:
            tracker.reset(X0, q_in, warn=False)               # the joints at t0 are the inputs
            return tracker, q_in
        joints = f"inputs ({', '.join(self.JOINTS)}) = ({', '.join(repr(float(v)) for v in q_in)})"
        if finite and tracker.reset(X0, q_in, warn=False).certain:
            # the inputs are not the joints of X0, but their DK solution within start_tolerance of X0 is
            # proved the robot's: the tracker starts there, at the inputs
            if log:
                msg = (f"initialization: {joints} are not the joints of the initial pose (x0, y0, phi0) in posture "
                       f"{self.posture} (largest difference {gap:.3g} rad > {self.Q0_TOL:g} rad); the tracker "
                       f"starts from their DK solution within start_tolerance of it, proved the robot's")
                self.log(msg, Fmi2Status.ok)
                self._pylog.info("%s", msg)
            return tracker, q_in
        why = tracker.start.reason if finite else "an input is not finite"
        tracker.reset(X0, q_ik, warn=False)
        if log:
            self._report(f"initialization: {joints} are not the joints of the initial pose (x0, y0, phi0) in "
                         f"posture {self.posture} (largest difference {gap:.3g} rad > {self.Q0_TOL:g} rad) and "
                         f"cannot start the tracker ({why}); the tracker starts from the inverse kinematics "
                         f"q = ({', '.join(repr(float(v)) for v in q_ik)}) and moves to the inputs at the first step",
                         Fmi2Status.warning)
        return tracker, q_ik

    def _initial_outputs(self, tracker, log):
        """Outputs at the initial configuration of ``tracker`` (just reset): its start pose, described like
        a step, certain and bounded as its honest start (``tracker.start``) says."""
        st, mt, start = tracker.state, tracker.map, tracker.start
        sol = dk_all(self._model, st.q, rule=mt.rule)
        real = sol.poses.real[sol.real]
        labels = np.flatnonzero(sol.real) + 1
        region = 0
        if len(real):
            d = np.abs(real - st.X)
            d[:, 2] = np.abs(wrap_angle(d[:, 2]))
            region = int(labels[np.argmin(d.max(axis=1))])
        J, _ = jacobians(self._model, st.X, st.q)
        cond = float(abs(np.linalg.det(J)) / np.prod(np.linalg.norm(J, axis=1)))
        near = mt.near_labels(st.X, tracker.r, mt.default_weights)[1:]
        self.x, self.y, self.phi = (float(v) for v in st.X)
        self.region = region
        self.near_border = bool(np.count_nonzero(near) > 1)
        self.n_real = int(sol.n_real)
        self.ambiguous = False
        self.status = 2 if cond < self.SINGULAR_TOL else 0
        self.cond = cond
        self.certain = bool(start.certain)
        # an uncertain start: the episode begins at step 0, the start time
        self._since = None if start.certain else (0, float(self._time))
        self.uncertain_since = -1.0 if start.certain else float(self._time)
        self._publish_bound(start.certain, start.pose_bound, TRUST_CERTAIN if start.certain else TRUST_LOST)
        self._episode = self.status
        if log and self.status:
            self._report(f"initialization: the initial pose is {STATUS[self.status]} (cond {cond:.3g})",
                         Fmi2Status.warning)
        if log and not start.certain:
            self._report(f"initialization: the start is not certain (certain false, trust 0, no bound): "
                         f"{start.reason}", Fmi2Status.warning)

    def _publish_bound(self, certain, bound, trust):
        self.x_bound, self.y_bound, self.phi_bound = bound.tolist() if certain else (NO_BOUND,) * 3
        self.trust = int(trust)

    def initial_outputs(self):
        """In Initialization Mode: the outputs after the honest start from (x0, y0, phi0) at the inputs
        (those of exitInitializationMode); parameters it refuses: the initial pose, not certain."""
        try:
            tracker, _ = self._start(log=False)
        except ValueError:
            self.x, self.y, self.phi = float(self.x0), float(self.y0), float(wrap_angle(self.phi0))
            self.certain, self.uncertain_since = False, float(self._time)
            self._publish_bound(False, None, TRUST_LOST)
            return
        self._initial_outputs(tracker, log=False)

    # ------------------------------------------------------------------ stepping
    def _outputs(self):
        """The output values, in table order (``_output_attrs``)."""
        return self._output_values(self)

    def _solve(self, q, dt=None):
        """The tracker's step to ``q`` from the committed state, not committed: (X, info, state after).

        ``dt``: the time from the committed sample to this one (the doStep's step size; None when
        the outputs are read before doStep).  Cached by (q, dt, TrackerState object): doStep after
        a get of the outputs costs no second step when the time step agrees.
        """
        st = self._track
        c = self._cache
        if c is not None and c[0] == q and c[1] is st and c[5] == dt:
            return c[2], c[3], c[4]
        tr = self._tracker
        tr.restore(st)                            # free when the tracker holds it (the last step's)
        X, info = tr.step(np.array(q, dtype=float), dt=dt)
        after = tr.snapshot()
        self._cache = (q, st, X, info, after, dt)
        return X, info, after

    def _publish(self, X, info, t):
        """Set the outputs of a step whose sample is at time ``t``; returns ``_since`` after that step."""
        self.x, self.y, self.phi = X.tolist()
        self.region = int(info.label)
        self.near_border = bool(info.near_border)
        self.n_real = int(info.n_real)
        self.ambiguous = bool(info.ambiguous)
        self.status = int(info.status)
        self.cond = float(info.cond)
        if info.certain:
            since = None
        elif self._since is not None and self._since[0] == info.uncertain_since:
            since = self._since                   # the same episode: it began at that step's time
        else:
            since = (int(info.uncertain_since), float(t))
        self.certain = bool(info.certain)
        self.uncertain_since = -1.0 if since is None else since[1]
        self._publish_bound(info.certain, info.pose_bound, info.trust)
        self.out_of_budget = bool(info.out_of_budget)
        return since

    def _joints(self):
        """The joint inputs, in order (a tuple of floats)."""
        return tuple(getattr(self, name) for name in self.JOINTS)

    def step(self, t, dt):
        q = self._joints()
        share = self.step_budget_share
        self._tracker.step_budget = share * dt if share > 0.0 and dt > 0.0 else None
        # the tracker's extrapolation scales with the ratio of successive time steps (a master that
        # rolls back and evaluates Runge-Kutta stages steps by h/2 and h from the same state)
        X, info, after = self._solve(q, dt if dt > 0 else None)
        self._track = after                       # the only place the tracker state advances
        self._since = self._publish(X, info, t + dt)
        self._committed = (q, self._outputs())
        if info.status != self._episode:
            self._log_episode(t + dt, info)

    def evaluate(self):
        """Direct feedthrough: the outputs for the current q, seen from the committed state.

        q equal to the q of the last doStep (or of the initialization): that step's outputs.
        Another q: the step the tracker would take to it, computed but not committed.
        """
        if self._track is None:
            return
        q = self._joints()
        committed_q, outputs = self._committed
        if q == committed_q:
            for name, value in zip(self._output_attrs, outputs):
                setattr(self, name, value)
            return
        X, info, _ = self._solve(q)
        self._publish(X, info, self._time)        # tentative: the episode is not committed

    def _log_episode(self, t, info):
        q = f"({', '.join(self.JOINTS)}) = ({', '.join(repr(v) for v in self._joints())})"
        if info.status == 1:
            self._report(f"t={t!r}: {q} has no real direct-kinematics solution (outside the joint space); "
                         f"status 1 unreachable, pose held at (x, y, phi) = ({self.x!r}, {self.y!r}, "
                         f"{self.phi!r}) until q is reachable again", Fmi2Status.warning)
        elif info.status == 2:
            self._report(f"t={t!r}: {q} is at a singularity (cond {info.cond:.3g}); status 2 singular",
                         Fmi2Status.warning)
        elif info.status in STATUS and info.status:
            self._report(f"t={t!r}: {q}: status {info.status} {STATUS[info.status]}", Fmi2Status.warning)
        else:
            msg = f"t={t!r}: status 0 ok again at {q}, (x, y, phi) = ({self.x!r}, {self.y!r}, {self.phi!r})"
            self.log(msg, Fmi2Status.ok)
            self._pylog.info("%s", msg)
        self._episode = info.status

    def _refuse(self, t, dt, msg):
        # every refused doStep ends here (after the rollback): the state is that of the start of the
        # step; the outputs keep the last pose and say why nothing moved
        ok = super()._refuse(t, dt, msg)
        self.status = 3
        return ok

    # ------------------------------------------------------------------ FMU state
    def get_state(self):
        snap = super().get_state()
        track = self._track
        snap["_track"] = None if track is None else (
            TrackerState.from_array(track) if isinstance(track, np.ndarray) else track).as_array().tolist()
        return snap

    def set_state(self, snapshot):
        snap = dict(snapshot)
        track = snap.pop("_track")
        super().set_state(snap)
        self._track = None if track is None else TrackerState.from_array(track)
        self._cache = None
        if track is not None and (self._tracker is None or self._tracker.posture != self.posture
                                  or self._tracker.mode != self.MODES[self.mode]
                                  or (self._tracker.joint_tolerance, self._tracker.speed_bound,
                                      self._tracker.stuck_after, tuple(self._tracker.start_tolerance.tolist()),
                                      self._tracker.geometry_tolerance) != self._options()):
            self._tracker = self._make_tracker(self.posture, self.mode)
            self._dk_lane_connect()                  # the lane steps the new tracker
