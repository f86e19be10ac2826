"""The tracker fed by real sensors: errors, certainty and step time per sensor grade and method.

    python bench/bench_sensors.py [--suite all|default|hard] [--rate 1000] [--grades 16-bit 12-bit ...]
                                  [--methods default paper newton] [--out results]

Paths: the suites of :mod:`experiments.suite` (``default``: the paper circle and circles
passing 20, 5 and 1 mm from a type-1 singularity; ``hard``: all eight postures,
circles, ellipses and Lissajous figures passing 0.5 to 20 mm from one or far from
it), each sampled at ``--rate`` points per revolution (1000: a revolution a second
at 1 kHz), plus the suites at their own coarse samplings with ``--coarse``.
Sensors (:data:`experiments.sensors.SENSOR_GRADES`): exact joints; 16-, 14- and 12-bit
encoders with 1e-3 rad of white noise; outliers (0.1 rad, one sample), a stuck
joint (20 samples) and dropouts (NaN) on the 14-bit encoder, five per stream.

Trackers: ``joint_tolerance`` ``--sigmas`` noise sigmas plus half a step, ``stuck_after`` from the
sensor, and on each path a speed bound 1.25 times that path's fastest (:func:`solver.sensors.speed_bound`;
``--speed-scope suite``: the suite's fastest on every path, as runs before 2026-11-27).

Truth (:func:`experiments.sensors.sensor_truth`): the real DK solution of the measured
joints nearest to the noise-free pose, counted only where the second nearest is at
least three times farther and the sample is not a glitch.  On counted steps:

* errors: pose more than 1e-6 from the truth (x, y, wrapped phi);
* silent errors: errors reported ``certain``;
* false alarms: right steps not reported ``certain`` (vouching methods only);
* refused: samples the method refused (a dropout's NaN raises ``SolverInputError``,
  an outlier is status ``rejected``), counted or not;
* recovery: after a glitch that found the method right, the most good samples it
  then spent wrong (0: right at the first good sample).

Step time: the median over all steps of each method, measured in the same run, and its tail (99th and
99.9th percentiles, slowest step): the steps without a certificate search harder.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from bench_tracker import VOUCHING as _VOUCHING
from bench_tracker import pose_errors
from experiments.sensors import SENSOR_GRADES, sensor_truth
from experiments.suite import default_suite, hard_suite
from solver import DEFAULT_RULE, DEFAULT_STEP, Manipulator, SolverInputError, Tracker, cached_map, wrap_angle
from solver.baselines import BASELINES
from solver.sensors import speed_bound
from solver.tracker_state import STATUS

REJECTED = [k for k, v in STATUS.items() if v == "rejected"][0]
#: The default-constructed tracker ("bare"), and the same with only a speed bound given ("bare-speed", what its
#: warning asks for): exact grades only, reset at the first reading.
BARE = ("bare", "bare-speed")
#: Methods that vouch: the baselines' and the default-constructed trackers'.
VOUCHING = _VOUCHING + BARE


#: The benchmark's start poses are exact (noise-free pose and joints): a start tolerance of rounding.
EXACT_START = (1e-9, 1e-9, 1e-9)


def make_methods(model, maps, names, tol, speed, stuck_after=0):
    makers = {"default": lambda p: Tracker(model, maps[p], joint_tolerance=tol, speed_bound=speed,
                                           stuck_after=stuck_after, start_tolerance=EXACT_START),
              "bare": lambda p: Tracker(model, maps[p]),          # default construction (exact joints assumed)
              "bare-speed": lambda p: Tracker(model, maps[p], speed_bound=speed),
              "paper": lambda p: Tracker(model, maps[p], mode="paper", joint_tolerance=tol, speed_bound=speed,
                                         stuck_after=stuck_after, start_tolerance=EXACT_START)}
    for name, cls in BASELINES.items():
        makers[name] = (lambda c: (lambda p: c(model)))(cls)
    return {n: makers[n] for n in names}


def run_stream(tracker, q, X0, dt, bounds=None):
    """Track a measured stream sample by sample: poses (n, 3), certain (n,), refused (n,), step seconds (n,);
    the pose bounds (n, 3) into ``bounds`` when given (inf where not certain)."""
    n = len(q)
    X = np.full((n, 3), np.nan)
    certain = np.zeros(n, dtype=bool)
    refused = np.zeros(n, dtype=bool)
    secs = np.zeros(n)
    if bounds is not None:
        bounds[:] = np.inf
    start = tracker.reset(X0, q[0])
    X[0], certain[0] = tracker.state.X, True if start is None else start.certain
    if bounds is not None and start is not None:
        bounds[0] = start.pose_bound
    step = tracker.step
    for k in range(1, n):
        t0 = time.perf_counter()
        try:
            X[k], info = step(q[k], dt)
        except SolverInputError:
            secs[k] = time.perf_counter() - t0
            refused[k] = True
            X[k] = tracker.state.X
            continue
        secs[k] = time.perf_counter() - t0
        certain[k] = info.certain
        refused[k] = info.status == REJECTED
        if bounds is not None:
            bounds[k] = info.pose_bound
    return X, certain, refused, secs


def score(X, certain, refused, truth, counted, glitch, vouching):
    """Counts of one stream: counted, errors, silent, alarms, refused, recovery (most good samples to recover)."""
    right = pose_errors(X, truth) <= 1e-6
    c = counted.copy()
    c[0] = False
    wrong = c & ~right
    silent = wrong & certain if vouching else wrong
    alarms = c & right & ~certain if vouching else np.zeros_like(c)
    recovery = 0
    starts = np.nonzero(glitch[1:] & ~glitch[:-1])[0] + 1          # first glitch sample of each glitch
    for g in starts:
        if not (counted[g - 1] and right[g - 1]):
            continue                                             # wrong already before: not the glitch's doing
        k = g
        while k < len(right) and glitch[k]:
            k += 1
        j = k                                                    # the good samples until right again
        while j < len(right) and counted[j] and not right[j]:
            j += 1
        recovery = max(recovery, j - k + (1 if j < len(right) and not right[j] else 0))
    return dict(counted=int(c.sum()), errors=int(wrong.sum()), silent=int(silent.sum()), alarms=int(alarms.sum()),
                refused=int(refused.sum()), recovery=recovery)


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--suite", choices=("all", "default", "hard"), default="all", help="which paths (default all)")
    ap.add_argument("--rate", type=int, default=1000, help="samples per revolution (1000: 1 kHz, 1 rev/s)")
    ap.add_argument("--coarse", action="store_true", help="also the suites at their own samplings")
    ap.add_argument("--grades", nargs="+", default=[s.name for s in SENSOR_GRADES],
                    help="sensor grades (experiments.sensors.SENSOR_GRADES; default all)")
    ap.add_argument("--methods", nargs="+", default=["default", "bare", "paper", "newton"],
                    help="trackers and baselines to run (default: default bare paper newton; bare, the "
                         "default-constructed tracker, and bare-speed, the same with a speed bound, run on "
                         "the grades without noise)")
    ap.add_argument("--no-floor", dest="floor", action="store_false",
                    help="skip the fold floor (bench/sensor_oracle.py's fold test on the default mode's "
                         "uncertain steps)")
    ap.add_argument("--limit", type=int, default=0, help="only the first N paths (quick looks)")
    ap.add_argument("--no-tolerance", dest="tolerance", action="store_false",
                    help="run the trackers without the sensor's joint_tolerance (as for exact joints)")
    ap.add_argument("--speed", type=float, nargs=2, default=None, metavar=("M_PER_S", "RAD_PER_S"),
                    help="the trackers' speed_bound on every path (default: each path's own, --speed-scope)")
    ap.add_argument("--speed-scope", choices=("path", "suite"), default="path",
                    help="without --speed: 1.25 times the path's own fastest speeds (path, default: what a "
                         "controller that planned the motion knows) or the fastest of the whole suite's (suite)")
    ap.add_argument("--no-speed", action="store_true", help="no speed bound (re-acquisition over the tool space)")
    ap.add_argument("--no-stuck", dest="stuck", action="store_false",
                    help="run the trackers without the stuck-joint detector (solver.stuck)")
    ap.add_argument("--sigmas", type=float, default=3.0, help="joint_tolerance = this many noise sigmas + half a step")
    ap.add_argument("--out", default="results", help="folder of sensor_suite.csv (default results)")
    return ap


def _suite_and_speed(model, args, dt: float):
    """The paths of ``--suite`` and the suite-wide speed bound (None: none): ``--speed``, else the
    largest of the paths' :func:`solver.sensors.speed_bound`."""
    suite = []
    if args.suite in ("all", "default"):
        suite += default_suite(model, samplings=(args.rate,) + ((1000, 300, 100, 30) if args.coarse else ()))
    if args.suite in ("all", "hard"):
        suite += hard_suite(model, samplings=(args.rate,) + ((30, 50, 100, 200) if args.coarse else ()))
    if args.limit:
        suite = suite[:args.limit]
    if args.speed is None and not args.no_speed:
        bounds = np.array([speed_bound(p.X, dt) for p in suite])
        args.speed = tuple(float(v) for v in bounds.max(axis=0))
    return suite, None if args.no_speed else tuple(args.speed)


def speed_of(path, speed, args, dt: float):
    """The speed bound the trackers get on ``path``: none, the one for every path (``--speed``, or
    ``--speed-scope suite``: the suite-wide ``speed``), else the path's own: 1.25 times its fastest
    (:func:`solver.sensors.speed_bound`), what a controller that planned the motion knows."""
    if speed is None or args.speed_scope == "suite":
        return speed
    return speed_bound(path.X, dt)


def longest_run(flags) -> int:
    """The longest run of True in ``flags`` (n,) bool."""
    best = cur = 0
    for f in flags:
        cur = cur + 1 if f else 0
        best = max(best, cur)
    return best


def bound_checks(X, bounds, certain, counted, X_true, q, q_true, tol):
    """The pose bound against the robot's (noise-free) pose on the counted certain steps where the sensor
    kept its tolerance: (steps checked, steps where it failed, ratios bound / actual error (m, 3))."""
    kept = np.all(np.abs(wrap_angle(q - q_true)) <= tol * (1 + 1e-12), axis=1)
    sel = counted & certain & kept
    sel[0] = False
    err = np.abs(X[sel] - X_true[sel])
    err[:, 2] = np.abs(wrap_angle(X[sel, 2] - X_true[sel, 2]))
    fail = np.any(err > bounds[sel], axis=1)
    return int(sel.sum()), int(fail.sum()), bounds[sel] / np.maximum(err, 1e-300)


def _run_grade(model, maps, suite, sensor, args, speed, dt, secs, worst, per_path) -> dict:
    """Every method on every path's stream of ``sensor``; the totals per method."""
    tol = sensor.tolerance(args.sigmas) if args.tolerance else 0.0
    names = [m for m in args.methods if m not in BARE or (sensor.noise == 0.0 and not sensor.glitch)]
    stuck = sensor.stuck_after() if args.stuck else 0
    tot = {m: dict(counted=0, errors=0, silent=0, alarms=0, refused=0, recovery=0, run=0, checked=0, broken=0,
                   ratios=[], floor=0) for m in names}
    rng = np.random.default_rng(7)
    for i, path in enumerate(suite):
        stream = sensor.measure(path.q, seed=1000 + i)
        q = stream.q.copy()
        q[0] = path.q[0]                                      # the tracker starts from a known configuration
        truth, counted = sensor_truth(model, q, path.X, stream.glitch)
        makers = make_methods(model, maps, names, tol, speed_of(path, speed, args, dt), stuck)
        for m, make in makers.items():
            bounds = np.empty((len(q), 3))
            qm = q
            if m in BARE:                     # as a new user would: reset at the first reading, not the exact joints
                qm = q.copy()
                qm[0] = stream.q[0]
            X, certain, refused, s = run_stream(make(path.posture), qm, path.X[0], dt, bounds)
            sc = score(X, certain, refused, truth, counted, stream.glitch, m in VOUCHING)
            secs.setdefault(m, []).append(s[1:])
            for key in ("counted", "errors", "silent", "alarms", "refused"):
                tot[m][key] += sc[key]
            tot[m]["recovery"] = max(tot[m]["recovery"], sc["recovery"])
            if m in VOUCHING:
                c = counted.copy()
                c[0] = False
                tot[m]["run"] = max(tot[m]["run"], longest_run((c & ~certain)[c]))
                n_chk, n_bad, ratios = bound_checks(X, bounds, certain, counted, path.X, q, path.q,
                                                    tol if m not in BARE else 0.0)    # bare: exact joints
                tot[m]["checked"] += n_chk
                tot[m]["broken"] += n_bad
                tot[m]["ratios"].append(ratios)
                if m == "default" and args.floor and tol > 0:
                    from sensor_oracle import foldable
                    tot[m]["floor"] += sum(foldable(model, path.X[k], path.q[k], q[k], tol, rng, 8)
                                           for k in np.nonzero(c & ~certain)[0])
            if sc["silent"] or (m == "default" and sc["errors"] > 0):
                worst.setdefault((sensor.name, m), []).append((path.name, sc["errors"], sc["silent"], sc["alarms"]))
            per_path[sensor.name, path.name, m] = sc["errors"]
    return tot


def main(argv=None):
    args = _parser().parse_args(argv)
    if args.speed is not None:
        args.speed_scope = "suite"                            # the bound given, on every path
    model = Manipulator.paper()
    dt = 1e-3
    suite, speed = _suite_and_speed(model, args, dt)
    grades = {s.name: s for s in SENSOR_GRADES}
    maps = {p: cached_map(model, p, DEFAULT_RULE, DEFAULT_STEP) for p in sorted({s.posture for s in suite})}
    rows, per_path, worst = {}, {}, {}
    secs = {}
    warm = make_methods(model, maps, args.methods, 1e-3, speed, 5)     # compile (or load) the kernels first
    for make in warm.values():
        run_stream(make(suite[0].posture), suite[0].q[:20], suite[0].X[0], dt)
    t_start = time.perf_counter()
    for gname in args.grades:
        rows[gname] = _run_grade(model, maps, suite, grades[gname], args, speed, dt, secs, worst, per_path)
    elapsed = time.perf_counter() - t_start
    tol = ", ".join(f"{g} {grades[g].tolerance(args.sigmas) * 1e3:.3g} mrad" for g in args.grades)
    print(f"{len(suite)} paths at {args.rate} samples per revolution, dt = 1 ms, {elapsed:.0f} s; joint_tolerance "
          f"{args.sigmas:g} sigma + half a step ({tol if args.tolerance else 'off'}); speed_bound "
          f"{_speed_text(speed, args)}")
    _print_tables(rows, grades, secs, suite, args.grades, per_path, worst)
    _write_csv(rows, Path(args.out) / "sensor_suite.csv")
    _report(rows, grades, secs, len(suite), elapsed, per_path, [p.name for p in suite], _speed_text(speed, args))


def _speed_text(speed, args) -> str:
    """How the run bounded the platform's speed, for the printed and published headers."""
    if speed is None:
        return "none"
    if args.speed_scope == "suite":
        return f"{speed[0]:.2f} m/s, {speed[1]:.2f} rad/s on every path"
    return (f"1.25 times each path's fastest (at least 0.5 rad/s; at most {speed[0]:.2f} m/s, "
            f"{speed[1]:.2f} rad/s)")


def trust_rows(rows) -> list:
    """Per sensor grade and vouching tracker: false alarms beside the fold floor, the longest run of
    uncertain counted steps, the pose bound's check and its tightness (table rows of strings)."""
    out = []
    for gname, tot in rows.items():
        for m, t in tot.items():
            if m not in ("default", "paper") + BARE:
                continue
            n = max(t["counted"], 1)
            r = np.concatenate(t["ratios"]) if t["ratios"] else np.empty((0, 3))
            tight = ", ".join(f"{v:.3g}" for v in np.median(r, axis=0)) if len(r) else "-"
            floor = f"{100 * t['floor'] / n:.2f} %" if m == "default" and gname != "exact" and t["floor"] else "-"
            out.append((gname, m, f"{100 * t['alarms'] / n:.2f} %", floor, str(t["run"]),
                        f"{t['checked'] - t['broken']:,} of {t['checked']:,}", tight))
    return out


TRUST_HEADER = ["sensor", "method", "false alarms", "fold floor", "longest uncertain run (steps)",
                "bound holds (certain steps, sensor within tolerance)", "bound / actual error, median (x, y, phi)"]


def _print_tables(rows, grades, secs, suite, grade_names, per_path, worst) -> None:
    print("\n| sensor | method | counted steps | errors | silent errors | false alarms | refused | recovery (samples) |")
    print("|---|---|---|---|---|---|---|---|")
    for gname, tot in rows.items():
        for m, t in tot.items():
            fa = f"{t['alarms']} ({100 * t['alarms'] / max(t['counted'], 1):.2f} %)" if m in VOUCHING else "n/a"
            rec = str(t["recovery"]) if grades[gname].glitch else "-"
            print(f"| {gname} | {m} | {t['counted']:,} | {t['errors']} | {t['silent']} | {fa} | {t['refused']} | {rec} |")
    print("\n| " + " | ".join(TRUST_HEADER) + " |\n|" + "---|" * len(TRUST_HEADER))
    for row in trust_rows(rows):
        print("| " + " | ".join(row) + " |")
    med = {m: 1e6 * float(np.median(np.concatenate(v))) for m, v in secs.items()}
    print("\n| method | median step time (us), all streams | 99th percentile (us) | 99.9th (us) | slowest (ms) |"
          "\n|---|---|---|---|---|")
    for m, v in med.items():
        a = 1e6 * np.concatenate(secs[m])
        print(f"| {m} | {v:.1f} | {np.percentile(a, 99):.0f} | {np.percentile(a, 99.9):.0f} | {a.max() / 1e3:.1f} |")
    if "newton" in med and "default" in med:
        print(f"\nstep time default / newton: {med['default'] / med['newton']:.2f}x (<= 3x)")
        for gname in grade_names:
            worse = [p.name for p in suite if per_path[gname, p.name, "default"] > per_path[gname, p.name, "newton"]]
            print(f"{gname}: paths where the default mode errs more often than newton: {len(worse)} of {len(suite)}"
                  + (f" ({', '.join(worse[:6])}{' ...' if len(worse) > 6 else ''})" if worse else ""))
    if worst:
        print("\npaths with silent errors, or default-mode errors (path, errors, silent, alarms):")
        for (g, m), lst in worst.items():
            print(f"  {g} {m}: " + "; ".join(f"{p} {e}/{s}/{a}" for p, e, s, a in lst[:8])
                  + (f" ... ({len(lst)} paths)" if len(lst) > 8 else ""))


def _write_csv(rows, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w") as f:
        f.write("sensor,method,counted,errors,silent_errors,false_alarms,refused,recovery\n")
        for gname, tot in rows.items():
            for m, t in tot.items():
                f.write(f"{gname},{m},{t['counted']},{t['errors']},{t['silent']},{t['alarms']},{t['refused']},"
                        f"{t['recovery']}\n")


def _report(rows, grades, secs, n_paths, elapsed, per_path, names, speed_text):
    """The totals per sensor and method and the step times into docs/benchmarks.md (bench/report.py)."""
    from report import publish, table, target
    lines = []
    for gname, tot in rows.items():
        for m, t in tot.items():
            fa = f"{t['alarms']:,} ({100 * t['alarms'] / max(t['counted'], 1):.2f} %)" if m in VOUCHING else "n/a"
            lines.append((gname, m, f"{t['counted']:,}", f"{t['errors']:,}", f"{t['silent']:,}", fa,
                          f"{t['refused']:,}", t["recovery"] if grades[gname].glitch else "-"))
    counts = table(["sensor", "method", "counted steps", "errors", "silent errors", "false alarms", "refused",
                    "recovery (samples)"], lines)
    times = []
    for m, v in secs.items():
        a = 1e6 * np.concatenate(v)
        times.append((m, f"{np.median(a):.1f} us", f"{np.percentile(a, 99):.0f} us", f"{np.percentile(a, 99.9):.0f} us",
                      f"{a.max() / 1e3:.1f} ms"))
    steps = table(["method", "median step", "99th percentile", "99.9th percentile", "slowest"], times)
    counts += "\n\n" + table(TRUST_HEADER, trust_rows(rows))
    worse = {g: [n for n in names if per_path[g, n, "default"] > per_path[g, n, "newton"]]
             for g in rows if "default" in rows[g] and "newton" in rows[g]}
    if worse:
        steps += "\n\n" + table(["sensor", "paths where the default mode errs more often than Newton"],
                                 [(g, f"{len(w)} of {n_paths}" + (f": {', '.join(w[:4])}{' ...' if len(w) > 4 else ''}"
                                                                  if w else "")) for g, w in worse.items()])
    noisy = [g for g in rows if g != "exact" and "default" in rows[g]]
    headline = None
    if noisy:
        d = [rows[g]["default"] for g in noisy]
        real = [g for g in noisy if grades[g].noise <= 1e-4 and not grades[g].glitch]
        harsh = [g for g in noisy if grades[g].noise > 1e-4 and not grades[g].glitch]
        pct = {g: 100 * rows[g]["default"]["alarms"] / max(rows[g]["default"]["counted"], 1) for g in noisy}
        floor = {g: 100 * rows[g]["default"]["floor"] / max(rows[g]["default"]["counted"], 1) for g in noisy}
        checked = sum(rows[g][m]["checked"] for g in noisy for m in rows[g] if m in ("default",) + BARE)
        broken = sum(rows[g][m]["broken"] for g in noisy for m in rows[g] if m in ("default",) + BARE)
        headline = [(f"joints from encoders ({', '.join(noisy)}), default mode: silent errors / errors",
                     f"{sum(t['silent'] for t in d)} / {sum(t['errors'] for t in d):,}"
                     + (f" (Newton: {sum(rows[g]['newton']['errors'] for g in noisy):,}, all silent)"
                        if all("newton" in rows[g] for g in noisy) else ""), "0 silent")]
        if real:
            ok = all(pct[g] <= 1.0 and rows[g]["default"]["run"] <= 50 for g in real)
            headline.append((f"realistic encoders ({', '.join(real)}): false alarms; longest uncertain run",
                             ", ".join(f"{pct[g]:.2f} %" for g in real) + "; "
                             + ", ".join(str(rows[g]["default"]["run"]) for g in real) + " steps",
                             target("<= 1 %, <= 50 steps", ok)))
        if harsh:
            ok = all(pct[g] <= floor[g] + 3.0 for g in harsh)
            headline.append((f"harsh encoders ({', '.join(harsh)}): false alarms (fold floor)",
                             ", ".join(f"{pct[g]:.1f} % ({floor[g]:.1f} %)" for g in harsh),
                             target("<= floor + 3 points", ok)))
        if "bare" in {m for g in rows for m in rows[g]}:
            bare = [g for g in rows if "bare" in rows[g]]
            share = [100 * rows[g]["bare"]["alarms"] / max(rows[g]["bare"]["counted"], 1) for g in bare]
            headline.append((f"default-constructed tracker ({', '.join(bare)}): false alarms",
                             ", ".join(f"{s:.2f} %" for s in share),
                             target("<= 1 %", max(share) <= 1.0)))
        headline.append(("pose bound holds (certain steps, sensor within its tolerance)",
                         f"{checked - broken:,} of {checked:,}", target("100 %", broken == 0)))
        if worse:
            headline.append(("the same: paths where the default mode errs more often than Newton",
                             ", ".join(f"{g} {len(worse[g])}" for g in noisy if g in worse) + f" of {n_paths}",
                             target("0", not any(worse[g] for g in noisy if g in worse))))
    publish("sensors", counts + "\n\n" + steps, headline=headline,
            note=f"{n_paths} paths at 1 kHz, {elapsed:.0f} s. Errors: the real DK solution of the measured joints "
                 "nearest the noise-free pose is the truth, counted where the second nearest is at least 3x farther. "
                 f"Speed bound: {speed_text}.")


if __name__ == "__main__":
    main()
