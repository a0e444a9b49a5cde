"""Fuzz the input readers: thousands of mutated injection logs (file reader and live decoder)
and event catalogues, with counts per outcome.

    python benchmarks/fuzz_inputs.py [--cases N] [--seed S]

Seeds are the bundled logs, the Basel 2006 log's first lines when present, and small catalogues
in CSV and FDSN text; each case applies a few mutations (bytes flipped, inserted or deleted;
lines duplicated, swapped or dropped; huge cells, lone CRs, BOMs and other encodings, stamps at
the calendar's edges, non-finite numbers, unclosed brackets with many blanks).  Outcomes:
``parsed``, ``project error`` (InjectionLogError / EventsError with a message), ``crash``
(any other exception) and ``hang`` (a case taking longer than 2 s plus 1 ms per kB; it is
interrupted).  The target is zero crashes and zero hangs; the first few of each are printed.
"""
from __future__ import annotations

import argparse
import collections
import random
import signal
import sys
import tempfile
import time
import traceback
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fault_screen.io.events import EventsError, read_events  # noqa: E402
from fault_screen.io.injection_log import InjectionLogError, read_injection_log  # noqa: E402
from fault_screen.io.log_format import LineSplitter  # noqa: E402
from fault_screen.io.log_stream import LogDecoder  # noqa: E402

BASEL = ROOT.parent / "shared" / "data" / "basel-2006" / "basel-2006-injection-1min.csv"


class Hang(Exception):
    pass


def seeds_logs():
    out = [p.read_bytes() for p in sorted((ROOT / "configs" / "logs").glob("*.csv"))]
    for base in (ROOT.parent / "shared", ROOT.parents[1] / "shared"):
        basel = base / "data" / "basel-2006" / "basel-2006-injection-1min.csv"
        if basel.exists():
            out.append(b"".join(basel.read_bytes().splitlines(keepends=True)[:200]))
            break
    out += [
        "Zeit;Débit (l/min);Druck [bar]\n12.03.2015 10:00:00;0,0;1,0\n12.03.2015 10:00:05;10,5;1,5\n"
        "12.03.2015 10:00:15;22,25;2,0\n".encode("latin-1"),
        "elapsed\tflow_rate[gpm]\n00:00:00\t0\n00:00:10\t5.5\n00:01:10\t6\n".encode("utf-16"),
        b"time,rate[L/min]\n23:59:50,10\n23:59:58,11\n00:00:07,12\n00:00:20,12\n",
        b"elapsed[min],dV[L]\n0,0\n1,10\n2,12\n3,0\n",
    ]
    return out


def seeds_catalogs():
    return [
        b"time,mag,mag_type,latitude,longitude,depth\n2015-03-12T10:00:00Z,0.5,ML,43.9,5.5,0.3\n"
        b"2015-03-12T10:05:00Z,-0.2,ML,43.9,5.5,0.28\n",
        b"#EventID|Time|Latitude|Longitude|Depth/km|Author|Catalog|Contributor|ContributorID|"
        b"MagType|Magnitude|MagAuthor|EventLocationName\n1|2015-03-12T10:00:00|43.9|5.5|0.3|a|b|c|d|"
        b"ML|0.5|e|f\n",
        b"origin_time;ML;x[m];y[m];z[m]\n2015-03-12 10:00:00;0,5;1;2;-280\n",
    ]


SPECIAL = [b"\r", b"\r\n", b"\n", b"\x00", b"\xff\xfe", b"\xef\xbb\xbf", b"\"", b";", b",", b"\t",
           b"inf", b"nan", b"-1e309", b"0001-01-01T00:00:00+14:00", b"9999-12-31T23:59:59-12:00",
           b"[" + b" " * 3000, b"(" + b" " * 3000, b"9" * 200_000, b"#", b"\xe9", b"1e-400"]


def mutate(rng: random.Random, data: bytes) -> bytes:
    b = bytearray(data)
    for _ in range(rng.randint(1, 5)):
        op = rng.choice(["flip", "insert", "delete", "special", "dup", "swap", "drop", "encode"])
        k = rng.randrange(len(b) + 1)
        if op == "flip" and b:
            b[min(k, len(b) - 1)] ^= rng.randrange(1, 256)
        elif op == "insert":
            b[k:k] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 8)))
        elif op == "delete" and b:
            del b[k:k + rng.randint(1, 8)]
        elif op == "special":
            b[k:k] = rng.choice(SPECIAL)
        elif op in ("dup", "swap", "drop"):
            lines = bytes(b).split(b"\n")
            if len(lines) > 1:
                i, j = rng.randrange(len(lines)), rng.randrange(len(lines))
                if op == "dup":
                    lines.insert(j, lines[i])
                elif op == "swap":
                    lines[i], lines[j] = lines[j], lines[i]
                else:
                    del lines[i]
                b = bytearray(b"\n".join(lines))
        elif op == "encode":
            text = bytes(b).decode("latin-1")
            b = bytearray(text.encode(rng.choice(["utf-16", "utf-8-sig", "cp1252"]), "replace"))
    return bytes(b)


def classify(fn, errors, size):
    budget = 2.0 + size / 1e6
    signal.setitimer(signal.ITIMER_REAL, budget)
    try:
        fn()
        return "parsed", None
    except Hang:
        return "hang", None
    except errors as exc:
        return ("project error", None) if str(exc).strip() else ("crash", "empty message")
    except Exception:  # noqa: BLE001 - what the fuzzer counts
        return "crash", traceback.format_exc(limit=4)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)


def live(data: bytes, options: dict, chunk: int):
    dec = LogDecoder("<fuzz>", **options)
    lines = LineSplitter()
    for k in range(0, len(data), chunk):
        dec.feed_lines(lines.push(data[k:k + chunk]))
    dec.feed_lines(lines.rest())
    dec.end()


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=3000, help="cases per reader")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()

    def on_alarm(signum, frame):
        raise Hang()
    signal.signal(signal.SIGALRM, on_alarm)
    rng = random.Random(args.seed)
    logs, cats = seeds_logs(), seeds_catalogs()
    counts = {k: collections.Counter() for k in ("log file reader", "live decoder", "catalogue reader")}
    shown = collections.Counter()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "case.csv"
        for case in range(args.cases):
            data = mutate(rng, rng.choice(logs))
            options = {"policy": rng.choice(["stop", "skip", "hold"])}
            if rng.random() < 0.3:
                options["tz"] = "Europe/Zurich"
            if rng.random() < 0.2:
                options["date"] = "2015-03-12"
            if rng.random() < 0.2:
                options["max_gap"] = None
            path.write_bytes(data)
            for reader, fn in (("log file reader", lambda: read_injection_log(path, **options)),
                               ("live decoder", lambda: live(data, options, rng.randint(1, 4096)))):
                kind, why = classify(fn, InjectionLogError, len(data))
                counts[reader][kind] += 1
                if kind in ("crash", "hang") and shown[reader] < 3:
                    shown[reader] += 1
                    print(f"--- {reader} {kind} on case {case} ({len(data)} bytes, {options}):\n"
                          f"{data[:300]!r}\n{why or ''}")
            cat = mutate(rng, rng.choice(cats))
            path.write_bytes(cat)
            bad_rows = rng.choice(["raise", "skip"])
            kind, why = classify(lambda: read_events(path, bad_rows=bad_rows, format="CSV"),
                                 EventsError, len(cat))
            counts["catalogue reader"][kind] += 1
            if kind in ("crash", "hang") and shown["catalogue reader"] < 3:
                shown["catalogue reader"] += 1
                print(f"--- catalogue {kind} on case {case}:\n{cat[:300]!r}\n{why or ''}")
    outcomes = ("parsed", "project error", "crash", "hang")
    print(f"\n{args.cases} mutated inputs per reader (seed {args.seed}), "
          f"{time.perf_counter() - t0:.0f} s")
    print(f"{'reader':18s}" + "".join(f"{o:>15s}" for o in outcomes))
    for reader, c in counts.items():
        print(f"{reader:18s}" + "".join(f"{c[o]:15d}" for o in outcomes))
    bad = sum(c["crash"] + c["hang"] for c in counts.values())
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
