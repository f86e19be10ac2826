"""The compiled step on the flat state (solver/_kernels/stepper.py) against the reference path that packs and
rebuilds a TrackerState object in Python at every step: bit for bit, state and outputs, for the tracker in
both modes, with measured joints, glitches, uneven time steps and a speed bound, and for every baseline;
``track``'s compiled loop against the step loop; snapshots; and a bad input leaving the state as it was."""
import numpy as np
import pytest

from solver import Tracker, circle_path, ik
from solver.baselines import BASELINES
from solver.checks import SolverInputError
from solver.tracker_state import TrackerError, TrackerState

from conftest import coarse_map

EXACT = (1e-9, 1e-9, 1e-9)


def _same(a, b) -> bool:
    return np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True)


def _streams(model):
    """(name, X, q) of the paper circle and of a circle passing 1 mm from a type-1 singularity (posture 1)."""
    from experiments.suite import near_singular_circle, NEAR_SINGULAR_SEEDS
    X = circle_path(120)
    posture, centre, phd = NEAR_SINGULAR_SEEDS[0]
    radius, _ = near_singular_circle(model, posture, centre, phd, 1e-3)
    Xs = circle_path(60, centre, radius, np.deg2rad(phd))
    return [("paper-circle", X, ik(model, X, 1)), ("near-singular", Xs, ik(model, Xs, posture))], posture


def _makers(model, maps):
    out = {"default": lambda: Tracker(model, maps, start_tolerance=EXACT),
           "paper": lambda: Tracker(model, maps, mode="paper", start_tolerance=EXACT),
           "measured": lambda: Tracker(model, maps, joint_tolerance=1e-4, speed_bound=(2.0, 10.0))}
    for name, cls in BASELINES.items():
        out[name] = (lambda c: (lambda: c(model)))(cls)
    return out


def _inputs(name, q, rng):
    """The samples a tracker reads: exact joints, or (measured) noisy joints with a glitch every 17th sample
    and uneven time steps."""
    if name != "measured":
        return [(q[k], None) for k in range(1, len(q))]
    out = []
    for k in range(1, len(q)):
        qk = q[k] + rng.normal(0.0, 3e-5, 3)
        if k % 17 == 5:
            qk = qk + np.array([0.05, 0.0, 0.0])
        out.append((qk, 1e-3 * (1.0 + 0.5 * (k % 3))))
    return out


def test_the_compiled_step_is_the_reference_step_bit_for_bit(model):
    streams, posture = _streams(model)
    for name, make in _makers(model, coarse_map(model, 1)).items():
        for path, X, q in streams:
            if path == "near-singular" and posture != 1:
                continue
            fast, ref = make(), make()
            ref._objects = True
            for tr in (fast, ref):
                tr.reset(X[0], q[0], **({"warn": False} if isinstance(tr, Tracker) else {}))
            statuses = set()
            for k, (qk, dt) in enumerate(_inputs(name, q, np.random.default_rng(7)), start=1):
                Xa, ia = fast.step(qk, dt)
                Xb, ib = ref.step(qk, dt)
                assert _same(Xa, Xb), (name, path, k)
                for f in ia._fields:
                    assert _same(getattr(ia, f), getattr(ib, f)), (name, path, k, f)
                statuses.add(ia.status)
                if k % 5 == 0 or k == len(q) - 1:          # the whole state, as saved
                    assert _same(fast.state.as_array(), ref.state.as_array()), (name, path, k)
            if name == "measured":
                assert 3 in statuses                         # the glitches were refused on both paths


def test_track_runs_the_stream_compiled_with_the_step_loops_results(model):
    streams, _ = _streams(model)
    for name, make in _makers(model, coarse_map(model, 1)).items():
        if name == "measured":
            continue
        for path, X, q in streams[:1]:
            fast, ref = make(), make()
            ref._objects = True                              # track then steps in Python
            a, b = fast.track(q, X[0]), ref.track(q, X[0])
            for f in a._fields:
                if f != "seconds":
                    assert _same(getattr(a, f), getattr(b, f)), (name, f)
            assert np.all(a.seconds[1:] > 0) and a.seconds[0] == 0.0
            assert _same(fast.state.as_array(), ref.state.as_array())


def _tracked(model, maps, n_points, n_steps):
    """(tracker, q): an exact-start tracker of the paper circle of ``n_points``, ``n_steps`` steps on."""
    X = circle_path(n_points)
    q = ik(model, X, 1)
    tr = Tracker(model, maps, start_tolerance=EXACT)
    tr.reset(X[0], q[0])
    for k in range(1, n_steps):
        tr.step(q[k])
    return tr, q


def test_a_snapshot_restores_the_state_and_the_steps_after_it(model, coarse_map1):
    tr, q = _tracked(model, coarse_map1, 80, 30)
    snap = tr.snapshot()
    assert snap.flags.writeable is False
    assert _same(TrackerState.from_array(snap).as_array(), tr.state.as_array())
    ahead = [tr.step(q[k]) for k in range(30, 50)]
    tr.restore(snap)
    again = [tr.step(q[k]) for k in range(30, 50)]
    for (Xa, ia), (Xb, ib) in zip(ahead, again):
        assert _same(Xa, Xb) and _same(ia.pose_bound, ib.pose_bound) and ia.certain == ib.certain
    other = Tracker(model, coarse_map1, start_tolerance=EXACT)     # another tracker of the same options
    other.restore(snap)
    assert _same(other.step(q[30])[0], ahead[0][0])
    with pytest.raises(TrackerError, match="snap"):
        tr.restore(np.zeros(5))


def test_a_state_set_as_an_object_is_the_one_the_compiled_step_continues(model, coarse_map1):
    tr, q = _tracked(model, coarse_map1, 60, 20)
    saved = tr.state                                         # made from the flat state when read
    x20 = tr.step(q[20])[0]
    tr.step(q[21])
    tr.state = saved
    assert _same(tr.step(q[20])[0], x20)
    with pytest.raises(TrackerError, match="state"):
        tr.state = saved.as_array()


@pytest.mark.parametrize("bad", [np.array([np.nan, 0.0, 0.0]), np.array([0.0, np.inf, 0.0]), [0.1, 0.2],
                                 np.zeros(3, dtype=np.float32) + np.nan])
def test_a_refused_input_leaves_the_flat_state_as_it_was(model, coarse_map1, bad):
    X = circle_path(40)
    q = ik(model, X, 1)
    for make in (lambda: Tracker(model, coarse_map1, start_tolerance=EXACT), lambda: BASELINES["newton"](model)):
        tr, twin = make(), make()
        for t in (tr, twin):
            t.reset(X[0], q[0])
            for k in range(1, 6):                          # past the encoder-grid watch: the flat state
                t.step(q[k])
        before = tr.snapshot()
        assert isinstance(before, np.ndarray)
        before = TrackerState.from_array(before).as_array()
        with pytest.raises(SolverInputError, match="q"):
            tr.step(bad)
        with pytest.raises(SolverInputError, match="dt"):
            tr.step(q[6], dt=-1.0)
        assert _same(TrackerState.from_array(tr.snapshot()).as_array(), before)
        assert _same(tr.step(q[6])[0], twin.step(q[6])[0])


def test_a_baseline_that_vouches_proves_no_pose_bound(model):
    """NewtonSeparationTracker's ``certain`` is a heuristic: its pose bound is inf, not memory left over."""
    X = circle_path(50)
    q = ik(model, X, 1)
    res = BASELINES["newton-separation"](model).track(q, X[0])
    assert res.certain[1:].any()
    assert np.all(np.isinf(res.pose_bound[1:]))


def test_track_many_is_track_on_each_stream(model, coarse_map1):
    X1, X2 = circle_path(60), circle_path(40, (0.5, 0.3), 0.1, 0.2)
    streams = [ik(model, X1, 1), ik(model, X2, 1)]
    tr = Tracker(model, coarse_map1, start_tolerance=(1e-3, 1e-3, 5e-3))
    many = tr.track_many(streams, [X1[0], X2[0]])
    for res, q, X in zip(many, streams, (X1, X2)):
        one = Tracker(model, coarse_map1, start_tolerance=(1e-3, 1e-3, 5e-3)).track(q, X[0])
        assert _same(res.X, one.X) and _same(res.certain, one.certain) and _same(res.pose_bound, one.pose_bound)
    with pytest.raises(SolverInputError, match="X0s"):
        tr.track_many(streams, [X1[0]])


def test_restore_checks_an_array_that_is_not_a_snapshot(model, coarse_map1):
    """A saved array (TrackerState.as_array) is checked before it reaches the kernels (which do not check
    their bounds): a corrupt one is refused by name, a valid one restores."""
    tr, q = _tracked(model, coarse_map1, 60, 20)
    saved = tr.state.as_array()
    x20 = tr.step(q[20])[0]
    from solver._kernels.state_layout import _N_CAND, _N_PAVE
    corrupt = saved.copy()
    corrupt[_N_CAND] = 7.0
    with pytest.raises(TrackerError, match="state"):
        tr.restore(corrupt)
    corrupt = saved.copy()
    corrupt[_N_PAVE] = 1e6
    with pytest.raises(TrackerError, match="paving"):
        tr.restore(corrupt)
    tr.restore(saved)
    assert _same(tr.step(q[20])[0], x20)


def test_snapshots_reach_the_kernels_with_the_signatures_the_fmus_ship(model, coarse_map1):
    """A read-only array is another numba signature (a compile in the host, on its thread): snapshots are
    restored from their writable buffer and from_array copies; no kernel is typed read-only."""
    from solver._kernels.anytime import walk_floats
    from solver._kernels.stepper import copy_state
    tr = Tracker(model, coarse_map1, start_tolerance=EXACT, step_budget=2e-5)   # walks in the state
    X = circle_path(60)
    q = ik(model, X, 1)
    tr.reset(X[0], q[0])
    snaps = []
    for k in range(1, 40):
        tr.step(q[k])
        snaps.append(tr.snapshot())
    arrays = [snap for snap in snaps if isinstance(snap, np.ndarray)]   # (the encoder-grid watch's: objects)
    assert len(arrays) >= 30
    for snap in arrays[::-1]:                          # restores that miss the held one: copies
        tr.restore(snap)
        TrackerState.from_array(snap)
    from numba import types
    for kernel in (copy_state, walk_floats):
        for sig in kernel.signatures:
            assert all(t.mutable for t in sig if isinstance(t, types.Array)), (kernel, sig)


def test_a_copied_or_pickled_tracker_steps_on_its_own_arrays(model, coarse_map1):
    """The C entry point's table holds a tracker's array addresses: a deep copy or an unpickled tracker
    makes its own (it would step the original's data, or freed memory, otherwise)."""
    import copy
    import pickle

    X = circle_path(80)
    q = ik(model, X, 1)
    tr = Tracker(model, coarse_map1)
    tr.reset(X[0], q[0], warn=False)
    for k in range(1, 20):
        tr.step(q[k])
    twins = [copy.deepcopy(tr), pickle.loads(pickle.dumps(tr))]
    rows = [[(X_.tolist(), info.certain) for X_, info in (t.step(q[k]) for k in range(20, 60))] for t in twins]
    before = tr.snapshot().copy()
    reference = [(X_.tolist(), info.certain) for X_, info in (tr.step(q[k]) for k in range(20, 60))]
    assert rows[0] == rows[1] == reference
    assert twins[0]._table[0] != tr._table[0] and twins[1]._table[0] != tr._table[0]
    canonical = [TrackerState.from_array(t.snapshot()).as_array() for t in (*twins, tr)]
    assert np.array_equal(canonical[0], canonical[1], equal_nan=True)
    assert np.array_equal(canonical[0], canonical[2], equal_nan=True)
    assert not np.array_equal(before, np.asarray(tr.snapshot()))


def test_the_stream_table_refuses_result_blocks_of_another_stream(model, coarse_map1):
    """The stream loop reads every row count from the joints' array: a result block of another length
    (or dtype) would be written past its end, so the table refuses it, naming it; and the compiled loop
    itself steps nothing (returns 0, the blocks untouched) from a table whose rows disagree."""
    from solver._kernels.baseline_entry import baseline_entry
    from solver._kernels.c_entry import CMD_TRACK, entry, set_rows, stream_table
    from solver.step_info import track_blocks
    n = 5
    qs = ik(model, circle_path(n), 1)
    for tr in (Tracker(model, coarse_map1), BASELINES["newton"](model)):
        (floats, ints, bools), _ = track_blocks(n)
        table = stream_table(tr._table, qs, floats, ints, bools)
        assert table[0] == tr._table[0] and table is not tr._table
        (short, _, _), _ = track_blocks(n - 1)
        with pytest.raises(ValueError, match=r"'floats': expected shape \(65,\)"):
            stream_table(tr._table, qs, short, ints, bools)
        with pytest.raises(ValueError, match=r"'ints': expected shape \(7, 5\)"):
            stream_table(tr._table, qs, floats, ints[:, :3], bools)
        with pytest.raises(ValueError, match="'bools': expected a 2-D bool array"):
            stream_table(tr._table, qs, floats, ints, bools.astype(float))
        with pytest.raises(ValueError, match=r"'qs': expected shape \(5, 3\)"):
            stream_table(tr._table, qs[:, :2].copy(), floats, ints, bools)
        # past the Python check: rows that disagree (a block of n - 1 steps) make the loop step nothing
        tr.reset(circle_path(n)[0], qs[0])
        tr._flat_state()
        bad = tr._table.copy()
        set_rows(bad, dict(qs=qs, floats=short, ints=ints, bools=bools))
        before = short.copy()
        if isinstance(tr, Tracker):
            assert entry().ctypes(bad.ctypes.data, CMD_TRACK, 0.0, 0.0) == 0
        else:
            assert baseline_entry(int(bad.ctypes.data), CMD_TRACK, 0.0, 0.0) == 0
        assert _same(short, before) and not ints.any()


def test_track_takes_a_read_only_stream(model, coarse_map1):
    """A stream the caller cannot write (a memory-mapped file, np.frombuffer) is tracked as a writable copy
    would be: the compiled loop only reads it."""
    X = circle_path(60)
    q = ik(model, X, 1)
    frozen = q.copy()
    frozen.setflags(write=False)
    a = Tracker(model, coarse_map1, start_tolerance=EXACT).track(frozen, X[0])
    b = Tracker(model, coarse_map1, start_tolerance=EXACT).track(q, X[0])
    assert np.array_equal(a.X, b.X) and np.array_equal(a.certain, b.certain) and a.certain.all()


@pytest.mark.parametrize("how", ["deepcopy", "pickle"])
def test_a_copied_baseline_steps_its_own_arrays(model, how):
    """A baseline's compiled entry reads a table of its arrays' addresses (as the tracker's, tested above):
    a copy (deepcopy, pickle) makes its own table, steps as the original would and leaves the original's
    data alone."""
    import copy
    import pickle
    X = circle_path(40)
    q = ik(model, X, 1)
    for name in ("newton", "nearest"):
        tr, twin = BASELINES[name](model), BASELINES[name](model)
        for t in (tr, twin):
            t.reset(X[0], q[0])
            for k in range(1, 8):
                t.step(q[k])
        dup = copy.deepcopy(tr) if how == "deepcopy" else pickle.loads(pickle.dumps(tr))
        assert dup._table[0] != tr._table[0]
        before = TrackerState.from_array(tr.snapshot()).as_array()
        for k in range(8, 20):                              # the copy steps on: the original is untouched
            x_dup, info_dup = dup.step(q[k])
            x_twin, info_twin = twin.step(q[k])
            assert _same(x_dup, x_twin) and info_dup.label == info_twin.label
        assert _same(TrackerState.from_array(tr.snapshot()).as_array(), before)
        assert _same(tr.step(q[8])[0], BASELINES[name](model).track(q[:9], X[0]).X[8])
        assert _same(dup.track(q, X[0]).X, twin.track(q, X[0]).X)


def test_a_stream_the_loop_refuses_raises_and_leaves_the_state(model, coarse_map1, monkeypatch):
    """Past stream_table's checks, the compiled loop refuses a stream whose rows disagree, a first step
    outside 0..n or a cycle rate that is not positive (nothing stepped, nothing written); ``track`` then
    raises TrackerError naming the steps taken, the tracker's data left as the loop found it.  A stream
    it takes reports each step's seconds, in sum no more than the call's wall time."""
    import time
    import solver.baselines
    import solver.tracker_entry
    import solver.tracking
    from solver._kernels.baseline_entry import UNKNOWN_COMMAND, baseline_entry
    from solver._kernels.c_entry import CMD_PUBLISH, CMD_TRACK, IO_K0, IO_RATE, entry, stream_table
    from solver.step_info import track_blocks
    X = circle_path(30)
    q = ik(model, X, 1)
    for make, module in ((lambda: Tracker(model, coarse_map1, start_tolerance=EXACT), solver.tracker_entry),
                         (lambda: BASELINES["newton"](model), solver.baselines)):
        tr = make()
        t0 = time.perf_counter()
        res = tr.track(q, X[0])
        wall = time.perf_counter() - t0
        assert np.all(res.seconds[1:] > 0.0) and res.seconds.sum() <= wall
        # the loop's own guards: k0 out of 0..n, NaN, or no rate -> 0 steps, the blocks untouched
        tr.reset(X[0], q[0])
        tr._flat_state()
        blocks, fields = track_blocks(len(q))
        table = stream_table(tr._table, q, *blocks)
        call = ((lambda: entry().ctypes(table.ctypes.data, CMD_TRACK, 0.0, 0.0)) if module is solver.tracker_entry
                else (lambda: baseline_entry(int(table.ctypes.data), CMD_TRACK, 0.0, 0.0)))
        for k0, rate in ((-1.0, 1e9), (len(q) + 1.0, 1e9), (np.nan, 1e9), (1.0, 0.0), (1.0, np.nan)):
            tr._io[IO_K0], tr._io[IO_RATE] = k0, rate
            before, fresh = tr.state.as_array(), [b.copy() for b in blocks]
            assert call() == 0
            assert all(_same(b, f) for b, f in zip(blocks, fresh))
            tr.flat_advanced()                                # (what a C caller says: read the flat state anew)
            assert _same(tr.state.as_array(), before)
        if module is solver.baselines:
            assert baseline_entry(tr._table_address, CMD_PUBLISH, 0.0, 0.0) == UNKNOWN_COMMAND
        # a table the loop refuses (no stream rows): track raises, the data is what the loop started from
        # (the reset's, or after the encoder-grid watch's first readings stepped in Python)
        seen = []

        def refused(table, *arrays, tr=tr):
            seen.append(tr.state.as_array())
            return table.copy()

        monkeypatch.setattr(solver.tracking, "stream_table", refused)
        with pytest.raises(TrackerError, match=r"the compiled stream took 0 of \d+ steps"):
            tr.track(q, X[0])
        monkeypatch.undo()
        assert len(seen) == 1 and _same(tr.state.as_array(), seen[0])
