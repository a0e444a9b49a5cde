"""Before and after: the cases of performance.py run by two revisions, back to back.

    python benchmarks/before_after.py 0256734                       # against a commit, 3 rounds
    python benchmarks/before_after.py HEAD~3 --cases rustrel fine-T0.7-dip30 --rounds 2

The other revision is checked out in a temporary git worktree (removed at the end); each case
runs in a fresh process of each revision in turn, round after round (the revision first in a
round alternates), so that both see the same machine: on a shared machine, or one whose speed
drifts, only runs this close together compare. Each revision's numba cache is warmed first. The
scenes, and the error against the exact solution, are this tree's; the solver is each revision's.
Prints, per case and revision, the fastest and slowest wall time, CPU time, peak memory (max RSS
of the process), Newton iterations and slip error.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from performance import ROOT, SLIP_SCENES, _env, child  # noqa: E402

CASES = ["rustrel"] + SLIP_SCENES + ["fine-T0.7-dip30", "rustrel-200x201"]


def _summary(runs):
    def span(key, fmt):
        low, high = (fmt(v) for v in (min(r[key] for r in runs), max(r[key] for r in runs)))
        return low if low == high else f"{low}-{high}"

    out = [span("wall", lambda v: f"{v:.2f}") + " s", span("cpu", lambda v: f"{v:.2f}") + " s",
           span("peak_mb", lambda v: f"{v:.0f}") + " MB", str(runs[0]["newton"])]
    out.append(f"{100 * runs[0]['error']:.4f} %" if "error" in runs[0] else "-")
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("revision", help="the revision to compare this tree with (a commit, a branch)")
    ap.add_argument("--cases", nargs="*", default=CASES, choices=CASES)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    commit = subprocess.run(["git", "rev-parse", "--short", args.revision], cwd=ROOT, check=True,
                            capture_output=True, text=True).stdout.strip()
    with tempfile.TemporaryDirectory() as tmp:
        other = Path(tmp) / "tree"
        subprocess.run(["git", "worktree", "add", "--detach", "-q", str(other), commit], cwd=ROOT, check=True)
        try:
            trees = {commit: other, "this tree": ROOT}
            print(f"load average {os.getloadavg()[0]:.1f} at the start", file=sys.stderr)
            for tree in trees.values():   # numba's cache of each tree in place
                child("rustrel", _env(tree))
            results = {(case, name): [] for case in args.cases for name in trees}
            for k in range(args.rounds):
                order = list(trees.items())[::(-1) ** k]
                for case in args.cases:
                    for name, tree in order:
                        r = child(case, _env(tree))
                        results[case, name].append(r)
                        print(f"  round {k + 1} {case} {name}: {r['wall']:.2f} s", file=sys.stderr, flush=True)
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(other)], cwd=ROOT)
    print(f"load average {os.getloadavg()[0]:.1f} at the end; {args.rounds} rounds\n")
    print("| case | revision | wall | CPU | peak | Newton | slip error |\n|---|---|---|---|---|---|---|")
    for case in args.cases:
        for name in trees:
            runs = [r for r in results[case, name] if "timeout" not in r]
            cells = _summary(runs) if runs else ["stopped"] * 5
            print(f"| {case} | {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
