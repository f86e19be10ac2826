"""The tracking loop shared by the tracker and the baselines: reset, step, track.

A tracker is constant; :meth:`_TrackerBase.step` checks the inputs, lets its
:class:`TrackerState` pack itself for the compiled step (``_kernel``), and makes
the next state from the step's result pack (:meth:`TrackerState.after`: a rejected
or held sample moves only its counts), with the stuck-joint detector's
bookkeeping (:mod:`solver.stuck`).  The tracker's options and the
meaning of ``certain``: :mod:`solver.tracker`.
"""
from __future__ import annotations

import platform
import time

import numpy as np

from ._kernels.layout import (I_CERTAIN, INFO_I_SIZE, OUT_N_PAVE, OUT_N_TUBES, OUT_REGION, OUT_SIZE, OUT_X, STATE_SIZE,
                              STATUS_REJECTED, TRUST_CERTAIN, TRUST_LOST)
from ._kernels.c_entry import IO_K0, IO_RATE, stream_table
from ._kernels.clock import cycles_per_second, deadline_after
from ._kernels.state_layout import STATE_FLOATS
from ._kernels.stepper import NOT_FINITE, copy_state
from .checks import SolverInputError, as_array
from .direct_kinematics import kernel_constants
from .kinematics import wrap_angle
from .manipulators import MANIPULATOR_TYPES
from .step_info import STEP_FIELDS, StepInfo, TrackResult, result_views, track_blocks
from .stuck import reading_fields, repeat_counts, stuck_refusal
from .tracker_state import TrackerError, TrackerState


def _check_q(q) -> np.ndarray:
    """q as a float array (3,), or SolverInputError naming ``q`` (fast path for the common case)."""
    if isinstance(q, np.ndarray) and q.shape == (3,) and q.dtype == np.float64 and np.isfinite(q).all():
        return q
    arr = as_array("q", q, (3,))
    if arr.shape != (3,):
        raise SolverInputError(f"q: expected shape (3,), got {arr.shape}")
    return arr


class _TrackerBase:
    """reset / step / track shared by the tracker and the baselines."""

    name = "base"
    #: Identical readings in a row that mark a joint stuck (0: off); see :mod:`solver.stuck`.
    stuck_after = 0
    #: Readings still to check for an encoder grid after a reset at exact joints (see :class:`solver.Tracker`).
    _watch = 0
    #: Step with the state as a TrackerState object (the reference the compiled stepper is tested against).
    _objects = False

    def __init__(self, model):
        if not isinstance(model, tuple(MANIPULATOR_TYPES.values())):
            raise TrackerError(f"model: expected a Manipulator or an RPRManipulator, got {type(model).__name__}")
        self.model = model
        # a 3-RPR's legs have limits: the tool space its re-acquisition searches ends there
        self._limits = (model.rho_min, model.rho_max) if model.kind == "3-RPR" else None
        k = kernel_constants(model)
        self._model_pack, self._sample_to_sextic = k["pack"], k["sample_to_sextic"]
        self._w = np.array([1.0, 1.0, float(np.mean(model.platform_radius)) ** 2])
        # the state: a flat array the compiled step advances in place (_flat, live when _live), and the
        # TrackerState a caller reads or sets (_st, made from the array when asked for; see ``state``)
        self._flat = np.full(STATE_FLOATS, np.nan)
        self._live = False
        self._st: TrackerState | None = None
        self._held = None                                   # the snapshot the flat state still equals, if any
        self._state_pack = np.empty(STATE_SIZE)
        self._out_real = np.empty(OUT_SIZE)
        self._out_real[OUT_N_TUBES] = 0.0                  # a baseline's step leaves no cover of tubes,
        self._out_real[OUT_REGION:OUT_REGION + 6] = np.nan  # no set-membership region,
        self._out_real[OUT_N_PAVE] = 0.0                    # and no paving
        self._out_int = np.empty(INFO_I_SIZE, dtype=np.int64)
        self._views = result_views(self._out_real, self._out_int)   # what a step's StepInfo is read from
        #: seconds one step may take (None: no budget); only the tracker has anytime proofs
        self.step_budget: float | None = None

    #: What a copy (pickle, deepcopy) makes anew instead of copying: the result views and the compiled
    #: entry's table, its address, the joints' view into ``io`` (they look into this tracker's own arrays),
    #: the entry's ctypes function and address (a process's own) and the C caller's backup
    #: (:mod:`solver.tracker_entry`).
    _REMADE = ("_views", "_table", "_table_address", "_q_in", "_call", "_fn", "_backup")

    def __getstate__(self):
        return {k: v for k, v in self.__dict__.items() if k not in self._REMADE}

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._views = result_views(self._out_real, self._out_int)
        self._entry_table()

    def _entry_table(self) -> None:  # pragma: no cover - abstract
        """The compiled entry's table over the tracker's arrays, ``io`` and its joints' view ``_q_in`` (made
        at construction and by a copy): the tracker's :mod:`solver.tracker_entry`, a baseline's
        :mod:`._kernels.baseline_entry`."""
        raise NotImplementedError

    @property
    def state(self) -> TrackerState | None:
        """The tracker's data (:class:`TrackerState`; None before :meth:`reset`).  Setting it replaces the
        data as a whole (a saved state restored); the compiled step keeps it as a flat array
        (:meth:`TrackerState.as_array`'s floats) and makes the object when it is read."""
        if self._st is None and self._live:
            self._st = TrackerState.from_array(self._flat)
        return self._st

    @state.setter
    def state(self, st: TrackerState | None) -> None:
        if st is not None and not isinstance(st, TrackerState):
            raise TrackerError(f"state: expected a TrackerState or None, got {type(st).__name__}")
        self._st, self._live, self._held = st, False, None

    def snapshot(self):
        """The tracker's data now, for :meth:`restore`: a read-only copy of the flat state (cheap, about a
        microsecond: what the compiled step keeps; the floats past its counts of candidates, tubes, boxes
        and walk are unspecified), or the :class:`TrackerState` when that is what the tracker holds; None
        before :meth:`reset`.  ``TrackerState.from_array`` reads the array form (its ``as_array`` is the
        canonical one, to save)."""
        if not self._live:
            return self._st
        buf = np.empty(STATE_FLOATS)
        copy_state(self._flat, buf, True)
        snap = buf.view()                                  # read-only; its buffer is what restore copies from
        snap.flags.writeable = False
        self._held = snap
        return snap

    def restore(self, snap) -> None:
        """Make the tracker's data a :meth:`snapshot` (of this tracker or one of the same options)."""
        if isinstance(snap, np.ndarray):
            if snap is self._held and self._live:          # the tracker holds it still: nothing to copy
                return
            src = snap.base
            if snap.flags.writeable or not (isinstance(src, np.ndarray) and src.shape == (STATE_FLOATS,)
                                            and src.dtype == np.float64 and src.flags.writeable):
                # not a snapshot: an array of the saved form, checked before it reaches the kernels
                if snap.shape != (STATE_FLOATS,):
                    raise TrackerError(f"snap: expected a snapshot or {STATE_FLOATS} floats of "
                                       f"TrackerState.as_array, got shape {snap.shape}")
                self.state = TrackerState.from_array(snap)
                return
            copy_state(src, self._flat, False)
            self._st, self._live, self._held = None, True, snap
        else:
            self.state = snap

    def flat_advanced(self) -> None:
        """The live flat state was advanced in place by a C caller (:meth:`solver.Tracker.c_step`)."""
        self._st, self._held = None, None

    def _flat_state(self) -> np.ndarray:
        """The live flat state (made from the TrackerState when that was set); TrackerError without one."""
        if not self._live:
            if self._st is None:
                raise TrackerError(f"{self.name}: no state; call reset(X0, q0) first")
            self._flat[:] = self._st.as_array()
            self._live = True
        return self._flat

    def reset(self, X0, q0) -> None:
        """Start tracking from a known configuration.

        Parameters
        ----------
        X0 : array_like, shape (3,)
            Pose at ``q0`` (m, m, rad).
        q0 : array_like, shape (3,)
            Joints (rad).
        """
        X0 = as_array("X0", X0, (3,))
        q0 = as_array("q0", q0, (3,))
        if X0.shape != (3,) or q0.shape != (3,):
            raise SolverInputError(f"X0, q0: expected shapes (3,) and (3,), got {X0.shape} and {q0.shape}")
        X0 = X0.copy()
        X0[2] = wrap_angle(X0[2])
        self.state = TrackerState(X0, q0.copy(), None, 0.0, 0, float("nan"), anchor=X0, anchor_age=0.0,
                                  reading=q0.copy())

    def _kernel(self, q, deadline: float):               # pragma: no cover - abstract
        """Run the compiled step on joints ``q`` and the state pack ``_state_pack`` (written by
        :meth:`TrackerState.pack`) into the output packs, until the ``deadline``
        (:mod:`solver._kernels.clock`; 0.0: none)."""
        raise NotImplementedError

    def _walk(self) -> np.ndarray | None:
        """The unfinished tube chain the last step left (a copy), None when none (baselines: never)."""
        return None

    def _out_of_budget(self) -> bool:
        """The last step's deadline passed before its searches ended (baselines: never)."""
        return False

    def step(self, q, dt: float | None = None):
        """Track one step: the pose of the manipulator at joints ``q``.

        Parameters
        ----------
        q : array_like, shape (3,)
            Current joints (rad).
        dt : float, optional
            Time since the previous sample read (s), refused or not.  It scales the
            tool-space extrapolation and, with a speed bound, how far the platform can
            have moved (the ``dt`` of refused and held samples add up, however uneven).
            Without it the samples are taken as uniformly spaced and the speed bound
            is not used.

        Returns
        -------
        X : ndarray, shape (3,)
            Pose (m, m, rad); the previous pose when ``q`` is unreachable.
        info : StepInfo

        Raises
        ------
        SolverInputError
            ``q`` of the wrong shape or not finite; the state is unchanged.
        TrackerError
            No state yet (call :meth:`reset`).
        """
        if self._watch or self.stuck_after or self._objects:  # the encoder-grid watch, the stuck-joint detector
            return self._step_objects(q, dt)
        deadline = deadline_after(self.step_budget) if self.step_budget is not None else 0.0
        if type(q) is not np.ndarray or q.dtype is not _F64 or q.shape != (3,) or self._limits is not None:
            q = self._check_joints(q)                        # (a float array (3,) is checked finite compiled)
        a = self._flat if self._live else self._flat_state()
        if dt is None:
            dt = _NAN
        elif np.isfinite(dt) and dt > 0:
            dt = float(dt)
        else:
            raise SolverInputError(f"dt: expected a positive time step in s, got {dt!r}")
        self._held = None
        since = self._advance(q, dt, deadline, a)
        if since == NOT_FINITE:
            self._check_joints(q)                            # raises, naming q; nothing changed
        self._st = None                                      # the flat state moved on
        X, info = _from_views(self._views, since)
        if deadline and not info.certain and self._out_of_budget():
            info = info._replace(out_of_budget=True)
        return X, info

    def _check_joints(self, q) -> np.ndarray:
        """``q`` as a float array (3,) within the joint limits; SolverInputError naming it otherwise."""
        q = _check_q(q)
        if self._limits is not None and (np.any(q < self._limits[0]) or np.any(q > self._limits[1])):
            raise SolverInputError(f"q: expected leg lengths within the joint limits [{self._limits[0]}, "
                                   f"{self._limits[1]}] m, got {q.tolist()}")
        return q

    def _advance(self, q, dt: float, deadline: float, a: np.ndarray) -> int:  # pragma: no cover - abstract
        """The compiled step from the flat state ``a`` to joints ``q``, ``dt`` s on (NaN: unknown), advancing
        ``a`` in place (:mod:`._kernels.stepper`); returns the step's ``uncertain_since``."""
        raise NotImplementedError

    def _step_objects(self, q, dt):
        """:meth:`step` with the state as a :class:`TrackerState` (the encoder-grid watch and the stuck-joint
        detector, :mod:`solver.stuck`, work on it)."""
        deadline = deadline_after(self.step_budget) if self.step_budget is not None else 0.0
        q = self._check_joints(q)
        st = self.state
        if st is None:
            raise TrackerError(f"{self.name}: no state; call reset(X0, q0) first")
        if dt is not None and not (np.isfinite(dt) and dt > 0):
            raise SolverInputError(f"dt: expected a positive time step in s, got {dt!r}")
        if self._watch:                                      # readings after an exact start: on an encoder grid?
            self._watch_grid(q)
        extra = {}
        if self.stuck_after:
            repeats = repeat_counts(st, q)
            held = stuck_refusal(st, q, repeats, self.stuck_after, dt)
            if held is not None:                             # a stuck joint: back to the clean state, refused
                self.state = held
                return held.X.copy(), StepInfo(0, False, held.X.copy(), 0, 0.0, False, STATUS_REJECTED, False,
                                               0.0, 0.0, False, 0, max(len(held.candidates), 1), held.since(False))
            extra = reading_fields(st, q, repeats, dt)
        st.pack(self._state_pack, dt, self.stuck_after)
        self._kernel(q, deadline)
        of, oi = self._out_real, self._out_int
        certain = bool(oi[I_CERTAIN])
        info = _from_views(self._views, st.since(certain))[1]           # (the tracker's views of of, oi)
        if deadline and not certain and self._out_of_budget():
            info = info._replace(out_of_budget=True)
        self.state = new = st.after(q, dt, of, oi, extra, None if certain else self._walk())
        # an accepted step's pose is the new state's (one copy), a refused or held one a copy of the old
        return (new.X if new.steps > st.steps else of[OUT_X:OUT_X + 3].copy()), info

    def track(self, q_stream, X0) -> TrackResult:
        """Track a whole joint stream.

        Parameters
        ----------
        q_stream : array_like, shape (n, 3)
            Joints (rad); ``q_stream[0]`` is the configuration of ``X0``.
        X0 : array_like, shape (3,)
            Pose at ``q_stream[0]`` (m, m, rad).

        Returns
        -------
        TrackResult
        """
        q_stream = as_array("q_stream", q_stream, (3,))
        if q_stream.ndim != 2 or len(q_stream) < 1:
            raise SolverInputError(f"q_stream: expected shape (n, 3) with n >= 1, got {q_stream.shape}")
        if self._limits is not None:                             # a 3-RPR's legs: checked before any step
            out = np.flatnonzero(np.any((q_stream < self._limits[0]) | (q_stream > self._limits[1]), axis=1))
            if len(out):
                raise SolverInputError(f"q_stream: expected leg lengths within the joint limits [{self._limits[0]}, "
                                       f"{self._limits[1]}] m, got {q_stream[out[0]].tolist()} at row {out[0]} "
                                       f"({len(out)} rows outside)")
        n = len(q_stream)
        self.reset(X0, q_stream[0])
        blocks, out = track_blocks(n)                             # the result's arrays, views of three blocks
        start = getattr(self, "start", None)
        certain = start is None or start.certain                  # baselines start from X0 as given
        out["certain"][0], out["uncertain_since"][0] = certain, -1 if certain else 0
        out["trust"][0] = TRUST_CERTAIN if certain else TRUST_LOST
        X, Xp, bound = out["X"], out["X_pred"], out["pose_bound"]
        X[0] = Xp[0] = self.state.X
        if start is not None:
            bound[0] = start.pose_bound
        k = 1
        # the encoder-grid watch and the stuck-joint detector step in Python, the rest in one compiled loop
        while k < n and (self._watch or self.stuck_after or self._objects or not _CYCLES):
            t0 = time.perf_counter()
            X[k], info = self.step(q_stream[k])
            out["seconds"][k] = time.perf_counter() - t0
            Xp[k] = info.X_pred
            bound[k] = info.pose_bound
            for key, _ in STEP_FIELDS:
                out[key][k] = getattr(info, key)
            k += 1
        if k < n:
            self._track_compiled(np.ascontiguousarray(q_stream, dtype=float), k, blocks)
        return TrackResult(**out)

    def track_many(self, q_streams, X0s) -> list:
        """Track several joint streams, each from its own start (a batch of paths; each stream's loop
        compiled, as :meth:`track`).

        Parameters
        ----------
        q_streams : sequence of array_like, each shape (n_i, 3), or array_like (m, n, 3)
            The streams' joints (rad); ``q_streams[i][0]`` is the configuration of ``X0s[i]``.
        X0s : array_like, shape (m, 3)
            The streams' start poses (m, m, rad).

        Returns
        -------
        list of TrackResult
            One per stream, in order; the tracker is left at the end of the last.
        """
        X0s = as_array("X0s", X0s, (3,))
        if X0s.ndim != 2 or len(X0s) != len(q_streams):
            raise SolverInputError(f"X0s: expected shape ({len(q_streams)}, 3), one start pose per stream, got "
                                   f"{X0s.shape}")
        return [self.track(q, X0) for q, X0 in zip(q_streams, X0s)]

    def _track_compiled(self, qs: np.ndarray, k0: int, blocks: tuple) -> None:
        """Steps ``k0``.. of :meth:`track` (joints ``qs`` (n, 3)) in one call of the compiled entry, into the
        result's blocks (:func:`solver.step_info.track_blocks`); TrackerError when the loop took fewer
        steps (it refused its table, which :func:`._kernels.c_entry.stream_table` checks first)."""
        self._flat_state()
        if not qs.flags.writeable:              # (the loop only reads it; the table takes writable rows)
            qs = qs.copy()
        table = stream_table(self._table, qs, *blocks)
        self._io[IO_K0], self._io[IO_RATE] = k0, cycles_per_second()      # the loop writes each step's seconds
        try:
            steps = self._loop(table)
        finally:                                                  # the flat state moved on, even part way
            self._st, self._held = None, None
        if steps != len(qs) - k0:
            raise TrackerError(f"{self.name}: the compiled stream took {steps} of {len(qs) - k0} steps")

    def _loop(self, table: np.ndarray) -> int:  # pragma: no cover - abstract
        """The compiled stream of the stream ``table`` (``CMD_TRACK``) from the live flat state, ``io`` set:
        one call of the tracker's C entry point (:mod:`solver.tracker_entry`) or of a baseline's
        (:mod:`._kernels.baseline_entry`); returns the steps it took."""
        raise NotImplementedError


#: The compiled loop of track times its steps with the CPU's cycle counter (x86-64); elsewhere track steps
#: in Python.
_CYCLES = platform.machine().lower() in ("x86_64", "amd64")
#: the step's reader of its result (:meth:`StepInfo.from_views`), and dt when not given, looked up once
_from_views, _NAN = StepInfo.from_views, float("nan")
#: float64 in native byte order: a step's joints of this dtype (``is``, numpy's one instance) skip the conversion
_F64 = np.dtype(np.float64)


