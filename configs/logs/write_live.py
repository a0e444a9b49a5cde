"""Write an injection log line by line, as a logger would during an injection.

    python configs/logs/write_live.py configs/logs/rustrel-2015-standin.csv live.csv --speed 50

copies the comment and header lines of SOURCE to TARGET at once, then appends each data line
when its time comes: the time between two lines is the difference of their stamps divided by
--speed (1 = real time), or --interval seconds if given.  Every line is flushed and fsync'ed,
so a follower on another machine (network file system) sees it.  Standard library only.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from datetime import datetime


def stamp(cell: str):
    cell = cell.strip()
    try:
        return float(cell)
    except ValueError:
        txt = cell[:-1] + "+00:00" if cell[-1:] in "Zz" else cell
        return datetime.fromisoformat(txt).timestamp()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("source")
    ap.add_argument("target")
    ap.add_argument("--speed", type=float, default=20.0, help="times real time [20]")
    ap.add_argument("--interval", type=float, default=None, help="fixed seconds between lines")
    ap.add_argument("--quiet", action="store_true")
    a = ap.parse_args(argv)
    if not a.speed > 0:
        ap.error("--speed must be > 0")
    with open(a.source, encoding="utf-8") as fh:
        lines = fh.read().splitlines()
    head = 0
    while head < len(lines) and (not lines[head].strip() or lines[head].lstrip().startswith("#")):
        head += 1
    head += 1                                   # the header line
    with open(a.target, "w", encoding="utf-8") as out:
        out.write("\n".join(lines[:head]) + "\n")
        out.flush()
        os.fsync(out.fileno())
        prev = None
        t_wall = time.monotonic()
        for n, line in enumerate(lines[head:], start=1):
            if not line.strip() or line.lstrip().startswith("#"):
                continue
            t = stamp(line.split(",")[0])
            if prev is not None:
                t_wall += a.interval if a.interval is not None else max(0.0, t - prev) / a.speed
                time.sleep(max(0.0, t_wall - time.monotonic()))
            prev = t
            out.write(line + "\n")
            out.flush()
            os.fsync(out.fileno())
            if not a.quiet and n % 20 == 0:
                print(f"{n} lines written", file=sys.stderr)
    if not a.quiet:
        print(f"done: {a.target}", file=sys.stderr)


if __name__ == "__main__":
    main()
