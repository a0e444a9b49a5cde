"""Fuzz the scene loader: mutate the bundled scenes thousands of times and count what happens.

    python benchmarks/fuzz_scenes.py [--cases 3000] [--seed 1] [--timeout 2]

Each case is a bundled scene file (configs/**/*.toml) with one mutation (byte flips, deletions,
duplications, deep nesting, huge numbers, wrong types, bytes that are not UTF-8, a removed line,
rules with long or deep conditions and multi-line text). A worker process loads it with
``Scene.from_toml``; a scene that loads is written back with ``to_toml`` and must read back
equal, and its size estimate (what ``run`` and ``scene check`` do next) must come out. Outcomes:

- loaded: a Scene, written back and read back equal, its size estimated;
- scene error: a ``SceneError`` with a one-line message;
- crash: any other exception, a SceneError whose message is empty or spans lines, or a scene
  that does not read back equal;
- hang: no answer within ``--timeout`` seconds (the worker is killed and restarted).

The target is zero crashes and zero hangs. The table goes to stdout, the first few crashes and
hangs of each kind below it.
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import random
import re
import sys
import tempfile
from collections import Counter, defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
OUTCOMES = ("loaded", "scene error", "crash", "hang")
_NUMBER = re.compile(rb"(?<![A-Za-z_\[])-?\d+(\.\d+)?([eE][-+]?\d+)?")
_VALUE = re.compile(rb"^(\s*[\"A-Za-z0-9_\[\]. ]+?\s*=\s*)(.+)$", re.M)


# ---- mutations: each takes (bytes, rng) and returns bytes ---------------------------------------
def flip_bytes(data, rng):
    out = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        out[rng.randrange(len(out))] = rng.randrange(256)
    return bytes(out)


def delete_span(data, rng):
    i = rng.randrange(len(data))
    return data[:i] + data[i + rng.randint(1, 200):]


def duplicate_span(data, rng):
    i = rng.randrange(len(data))
    j = min(len(data), i + rng.randint(1, 300))
    k = rng.randrange(len(data))
    return data[:k] + data[i:j] + data[k:]


def remove_line(data, rng):
    lines = data.split(b"\n")
    del lines[rng.randrange(len(lines))]
    return b"\n".join(lines)


def _replace_value(data, rng, new: bytes):
    values = list(_VALUE.finditer(data))
    if not values:
        return data + b"\nx = " + new
    m = rng.choice(values)
    return data[:m.start(2)] + new + data[m.end(2):]


def deep_nesting(data, rng):
    depth = rng.choice([50, 500, 5000, 50000])
    kind = rng.choice(["array", "table", "parentheses"])
    if kind == "array":
        return _replace_value(data, rng, b"[" * depth + b"1.0" + b"]" * depth)
    if kind == "table":
        return _replace_value(data, rng, b"{a = " * depth + b"1" + b"}" * depth)
    when = "(" * depth + "peak_slip_rate > slip_rate_red" + ")" * depth
    return data + f'\n[[monitor.rules]]\nlevel = "red"\nwhen = "{when}"\n'.encode()


def huge_number(data, rng):
    numbers = list(_NUMBER.finditer(data))
    new = rng.choice([b"1e400", b"-1e999", b"1" + b"0" * rng.choice([20, 400, 5000]), b"1.7976931348623157e308",
                      b"inf", b"nan", b"-0.0", b"5e-324", b"9007199254740993", b"0x7fffffffffffffffff"])
    if not numbers:
        return data + b"\nx = " + new
    m = rng.choice(numbers)
    return data[:m.start()] + new + data[m.end():]


def wrong_type(data, rng):
    new = rng.choice([b'"text"', b'"12 parsecs"', b"true", b"[]", b"[1, 2, 3]", b"{}", b"{a = 1}",
                      b"1979-05-27T07:32:00Z", b'"1e999 GPa"', b'"nan MPa"', b"[[1, 2], [3]]",
                      b'[["a", "b"]]', b"-1", b"0", b'"\\u0000"', b'"' + b"x" * 100000 + b'"'])
    return _replace_value(data, rng, new)


def not_utf8(data, rng):
    i = rng.randrange(len(data) + 1)
    return data[:i] + rng.choice([b"\xff", b"\xc3\x28", b"\xed\xa0\x80", b"\x80\x80", b"\xfe\xff"]) + data[i:]


def rules(data, rng):
    kind = rng.choice(["or chain", "multi-line action", "missing key", "odd name", "bad level"])
    if kind == "or chain":
        when = " or ".join(["peak_slip_rate > slip_rate_red"] * rng.choice([10, 1000, 20000]))
        rule = f'level = "red"\nwhen = "{when}"'
    elif kind == "multi-line action":
        rule = 'level = "yellow"\nwhen = "peak_slip_rate > slip_rate_yellow"\naction = """stop\n\tnow\r\n"\\\\"""'
    elif kind == "missing key":
        rule = rng.choice(['level = "red"', 'when = "peak_slip_rate > 1"', 'hold = 5.0'])
    elif kind == "odd name":
        rule = 'level = "red"\nwhen = "peak_slip_rate > 1"\nname = "' + rng.choice(["", "a" * 100, "\\n", "\\u0007"]) + '"'
    else:
        rule = 'level = "purple"\nwhen = "peak_slip_rate > 1"'
    return data + f"\n[[monitor.rules]]\n{rule}\n".encode()


MUTATIONS = {f.__name__.replace("_", " "): f for f in (
    flip_bytes, delete_span, duplicate_span, remove_line, deep_nesting, huge_number, wrong_type, not_utf8, rules)}


# ---- the worker -------------------------------------------------------------------------------------
def _load(path: str) -> tuple[str, str]:
    import tomllib
    import warnings

    from fault_screen.scene import Scene, SceneError
    try:
        from fault_screen.discretisation import estimate_size
    except ImportError:  # a tree from before the estimate moved (to measure the old loader)
        from fault_screen.scene import estimate_size

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            scene = Scene.from_toml(path)
        except SceneError as exc:
            text = str(exc)
            if not text or "\n" in text:
                return "crash", f"SceneError message {'empty' if not text else 'on several lines'}: {text[:200]!r}"
            return "scene error", text[:200]
        except Exception as exc:  # noqa: BLE001 - counting what escapes is the point
            return "crash", f"{type(exc).__name__}: {str(exc)[:200]}"
        try:
            again = Scene.from_dict(tomllib.loads(scene.to_toml()), base_dir=Path(path).parent)
        except Exception as exc:  # noqa: BLE001
            return "crash", f"written back, does not read back: {type(exc).__name__}: {str(exc)[:200]}"
        if again != scene:
            return "crash", "written back, reads back different"
        try:
            estimate_size(scene)
        except Exception as exc:  # noqa: BLE001
            return "crash", f"size estimate: {type(exc).__name__}: {str(exc)[:200]}"
    return "loaded", ""


def _worker(conn):
    while True:
        path = conn.recv()
        if path is None:
            return
        conn.send(_load(path))


class Worker:
    def __init__(self, warm_up: Path):
        self.conn, child = mp.Pipe()
        self.proc = mp.Process(target=_worker, args=(child,), daemon=True)
        self.proc.start()
        self.run(str(warm_up), 300.0)  # the imports, outside any case's time

    def run(self, path: str, timeout: float):
        self.conn.send(path)
        if self.conn.poll(timeout):
            return self.conn.recv()
        self.proc.kill()
        self.proc.join()
        return None

    def close(self):
        self.conn.send(None)
        self.proc.join(5)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--timeout", type=float, default=2.0, help="seconds before a case counts as a hang")
    args = ap.parse_args(argv)
    rng = random.Random(args.seed)
    first = ROOT / "configs" / "rustrel-2015-calibrated.toml"
    worker = Worker(first)
    # the bundled scene files (not the calibration's parameter tables), loaded once unmutated
    seeds = [p for p in sorted((ROOT / "configs").rglob("*.toml")) if worker.run(str(p), 120.0)[0] == "loaded"]
    originals = {p: p.read_bytes() for p in seeds}
    counts = defaultdict(Counter)
    examples = defaultdict(list)
    with tempfile.TemporaryDirectory() as tmp:
        for case in range(args.cases):
            name, mutate = rng.choice(list(MUTATIONS.items()))
            seed = rng.choice(seeds)
            data = mutate(originals[seed], rng)
            path = Path(tmp) / f"case{case}.toml"
            path.write_bytes(data)
            got = worker.run(str(path), args.timeout)
            if got is None:
                got = ("hang", f"> {args.timeout:g} s")
                worker = Worker(first)
            outcome, detail = got
            counts[name][outcome] += 1
            if outcome in ("crash", "hang") and len(examples[(name, detail[:60])]) < 1:
                examples[(name, detail[:60])].append(f"{seed.relative_to(ROOT)}: {detail}")
            path.unlink()
    worker.close()

    width = max(len(n) for n in MUTATIONS) + 2
    print(f"{args.cases} mutations of {len(seeds)} bundled scenes (seed {args.seed}, hang = no answer "
          f"in {args.timeout:g} s)\n")
    print("mutation".ljust(width) + "".join(o.rjust(13) for o in OUTCOMES) + "total".rjust(8))
    total = Counter()
    for name in MUTATIONS:
        total.update(counts[name])
        print(name.ljust(width) + "".join(str(counts[name][o]).rjust(13) for o in OUTCOMES)
              + str(sum(counts[name].values())).rjust(8))
    print("all".ljust(width) + "".join(str(total[o]).rjust(13) for o in OUTCOMES) + str(sum(total.values())).rjust(8))
    if examples:
        print("\ncrashes and hangs, one example of each kind:")
        for (name, _), lines in sorted(examples.items()):
            for line in lines:
                print(f"  [{name}] {line}")
    return 1 if total["crash"] or total["hang"] else 0


if __name__ == "__main__":
    sys.exit(main())
