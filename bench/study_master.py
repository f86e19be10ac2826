"""Effect of the master's ordering and communication step on tracking the circle.

    python bench/study_master.py [--build-dir build]

Runs the default scenario (exact model, 2.5 s) with the Gauss-Seidel and the Jacobi master at
h = 1, 2 and 5 ms and prints the RMS joint tracking error after 0.5 s, the largest error, and the
largest |DK pose - true pose|.  Deterministic: these are accuracy numbers, not timings.
"""
from __future__ import annotations

import argparse

from cosim import ClosedLoop, Scenario, build_fmus
from cosim.unit import exit_process


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build-dir", default="build")
    args = ap.parse_args(argv)
    paths = build_fmus(args.build_dir)
    print("| master | h = 1 ms | h = 2 ms | h = 5 ms |")
    print("|---|---|---|---|")
    rows = []
    with ClosedLoop(paths) as loop:
        for order in ("gauss-seidel", "jacobi"):
            cells = []
            for h in (1e-3, 2e-3, 5e-3):
                res = loop.run(Scenario(order=order, h=h))
                e = abs(res.joint_error()[res.t >= 0.5 - 1e-12])
                cells.append(f"{res.rms_joint_error(0.5):.2e} rad (max {e.max():.1e}; DK-true {res.max_dk_error():.0e})")
            print(f"| {order} | " + " | ".join(cells) + " |")
            rows.append((order, *cells))
    _report(rows)


def _report(rows):
    """The table into docs/benchmarks.md (bench/report.py)."""
    from report import publish, table
    publish("master", table(["master", "h = 1 ms", "h = 2 ms", "h = 5 ms"], rows),
            headline=[("closed loop, exact model, Gauss-Seidel, h = 1 ms: RMS joint error after 0.5 s",
                       rows[0][1].split(" (")[0], "<= 1e-4 rad")],
            note="RMS joint tracking error after 0.5 s of the default scenario (exact model, 2.5 s), the largest "
                 "error, and the largest |DK pose - true pose|. Deterministic: accuracy, not timing.")


if __name__ == "__main__":
    main()
    exit_process(0)              # FMUs were loaded: skip the pythonfmu libraries' finalizers
