"""Latency of the live monitor: from a log line being appended to the alert being handed to the
alert hook.

    python benchmarks/monitor_latency.py [--lines 300] [--rate 1] [--poll 0.5]
    python benchmarks/monitor_latency.py --lookahead [--plan hold --plan stop] [--horizon 3600]
        [--lookahead-every 60] [--rate 5] [--members 4 [--vary PARAMS.toml] [--free KEYS]]
    python benchmarks/monitor_latency.py --beside [--blocks 4]
    python benchmarks/monitor_latency.py --handover [--repeat 60]
    python benchmarks/monitor_latency.py --advice [--horizon 1800] [--lookahead-every 300]
        [--until 1500] [--scene configs/rustrel-2015-impermeable.toml]

A writer thread appends the bundled Rustrel stand-in log, resampled to one sample per second of
log time, at --rate lines per second of wall time (1 = real time) to a file that the monitor
service (csv source, real stepper, scene configs/rustrel-2015-calibrated.toml, results streamed
to a file) follows.  So that
every step raises an alert, the screener of this benchmark toggles green/yellow at each step
(the real rules raise few alerts); the latency of a step is the wall time from the append of the
line that completed it (the first sample at or after the step's end) to its alert reaching the
hook.  Prints the median and 99th percentile with the poll interval and the mean wall time of a
step.  Goal: median well under one step's wall time plus the poll interval.

``--lookahead`` measures what the live look-ahead costs the live steps: two runs on the same
log, without and then with look-ahead refreshes (worker thread, forks taken between two steps),
both screened by the scene's own rules (the look-ahead needs them: no toggle).  The latency of a
step is then the wall time from the append of the line that completed it to the end of its
screening, when its alerts, had it any, are in the outbox (the stage hands them over as it
raises them, before the next step or a look-ahead fork).  Prints median, p95
and max of each run, the forks' wall time on the live thread, the refreshes made and skipped,
and the load average.  The poll (``--poll``: the source waits up to that long for new lines)
adds a wait of 0 to one poll interval to every latency, which hides a few milliseconds of
look-ahead cost: so each run also gives the latency from the stage being fed the line (after
the read: the live thread's own work), the live thread's CPU time per step (``thread_time`` of
the thread that runs the service over the whole run, divided by its steps: its polls of the
log, steps, screening, result writing, the forks and the handling of the refreshes' rows, never
the worker's look-ahead), the forks' CPU time, and each run with
look-ahead the difference of its medians from the run without, with a 95 % bootstrap interval
(``--bootstrap`` resamples of each run's latencies).  A short poll (``--poll 0.05``) and more
lines (``--lines 900``) narrow the interval.  With ``--members N`` a third run has the ensemble look-ahead: N parameter
draws of ``--vary`` (default: the calibration's parameters file, ``--free`` its keys varied),
each a model of its own stepped in the worker from the samples received.

``--advice`` measures what reusing the previous advice saves: one live run of the calibrated
scene (or ``--scene``; fed sample by sample, every refresh waited for) whose forecaster makes, at each refresh
and on the same look-ahead state, a fresh bisection and one that seeks its bracket around the
previous refresh's advice (``advise(..., near=)``, what the monitor does); prints per refresh
the look-aheads and the worker's CPU time of each and their rates' relative difference (the
bisection's tolerance is 2 %).

``--beside`` isolates what a worker thread costs the live thread: live steps of the calibrated
scene (no log, no polling) in alternating blocks alone and with a worker beside them stepping
forks continuously, once with the worker at the look-ahead's lower priority (nice +10) and once
at the same priority; prints the live steps' median and p95 wall time and the live thread's
median CPU time per step (the work, unchanged: what grows is waiting for a core or the GIL).

``--handover`` times what handing a refresh to the worker costs the live thread, in one run:
starting a thread for it (``Thread.start`` returns once the new thread runs: on busy cores a
wait for the scheduler) against putting it in the queue of a worker thread that waits for it
(what ``LiveLookAhead`` does); both workers at the look-ahead's priority, each refresh a small
matrix product, waited for before the next.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(1, str(ROOT / "plugins"))

from fault_screen import Scene  # noqa: E402
from fault_screen.io.injection_log import read_injection_log  # noqa: E402
from fault_screen.monitor.service import MonitorConfig, MonitorService  # noqa: E402


class Toggle:
    """A screener whose level flips at every step (one alert per step)."""

    def __init__(self):
        self.level = 0

    def update(self, time_, metrics, events=()):
        new = 1 - self.level
        tr = {"time": time_, "previous": self.level, "level": new, "rule": "benchmark toggle",
              "action": ""}
        self.level = new
        return [tr]


class Hook:
    """Alert sink recording when each alert arrives."""

    def __init__(self):
        self.arrived = {}

    def deliver(self, alert):
        self.arrived[alert["model_time"]] = time.perf_counter()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--lines", type=int, default=300, help="log lines to append [300]")
    ap.add_argument("--rate", type=float, default=1.0, help="lines per second of wall time [1]")
    ap.add_argument("--poll", type=float, default=0.5, help="poll interval, s [0.5]")
    ap.add_argument("--simulation", default=None,
                    help="MODULE:CLASS of the stepper [fault_screen.Simulation]")
    ap.add_argument("--lookahead", action="store_true",
                    help="compare the step latency without and with the live look-ahead")
    ap.add_argument("--plan", action="append", default=None, help="look-ahead plan [hold, stop]")
    ap.add_argument("--horizon", type=float, default=3600.0, help="look-ahead horizon, s [3600]")
    ap.add_argument("--lookahead-every", type=float, default=60.0,
                    help="model time between refreshes, s [60]")
    ap.add_argument("--beside", action="store_true",
                    help="live steps alone and with a worker thread beside them")
    ap.add_argument("--blocks", type=int, default=4, help="--beside: blocks of 10 steps [4]")
    ap.add_argument("--members", type=int, default=0,
                    help="--lookahead: also a run with an ensemble of this many members [0: none]")
    ap.add_argument("--vary", default=str(ROOT / "configs" / "calibration" / "rustrel-2015-parameters.toml"),
                    help="--members: the parameters file [the calibration's]")
    ap.add_argument("--free", default="fault.hydraulic_aperture,damage_zone.mobility",
                    help="--members: the keys varied [fault.hydraulic_aperture,damage_zone.mobility]")
    ap.add_argument("--seed", type=int, default=1, help="--members: the draws' seed [1]")
    ap.add_argument("--handover", action="store_true",
                    help="the live thread's wall time to hand a refresh to a new thread / a waiting one")
    ap.add_argument("--repeat", type=int, default=60, help="--handover: refreshes handed over [60]")
    ap.add_argument("--bootstrap", type=int, default=2000,
                    help="--lookahead: bootstrap resamples of the difference of medians [2000]")
    ap.add_argument("--advice", action="store_true",
                    help="advice CPU time per refresh, fresh and reusing the previous advice")
    ap.add_argument("--until", type=float, default=1500.0,
                    help="--advice: model time the live run goes to, s [1500]")
    ap.add_argument("--scene", default=str(ROOT / "configs" / "rustrel-2015-calibrated.toml"),
                    help="--advice: the scene [configs/rustrel-2015-calibrated.toml]")
    a = ap.parse_args(argv)
    if a.beside:
        return worker_beside(a.blocks)
    if a.handover:
        return handover(a.repeat)
    if a.advice:
        return advice_reuse(a)
    if a.lookahead:
        return compare_lookahead(a)
    logging.getLogger("fault_screen").setLevel(logging.ERROR)   # one alert per step: quiet

    scene = Scene.from_toml(ROOT / "configs" / "rustrel-2015-calibrated.toml")
    t, q = _log_samples(a.lines)
    sim_class = None
    if a.simulation:
        mod, _, name = a.simulation.partition(":")
        sim_class = getattr(importlib.import_module(mod), name)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "live.csv"
        path.write_text("elapsed[s],flow_rate[m3/s]\n")
        # the results stream to a file as in operation (what a step costs includes it)
        cfg = MonitorConfig(follow=str(path), idle_exit=max(3.0, 5 * a.poll + 2.0 / a.rate),
                            poll_interval=a.poll, outbox=Path(tmp) / "box.sqlite",
                            checkpoint_every=10**9, out=Path(tmp) / "live.h5")
        hook = Hook()
        service = MonitorService(scene, cfg, sinks={"bench": hook}, simulation_class=sim_class,
                                 screener=Toggle(), metrics=lambda row, sc: {})
        sim = service.stage.sim
        advance, steps_wall = sim.advance, []

        def timed_advance(*args, **kw):
            w0 = time.perf_counter()
            n = advance(*args, **kw)
            if n:
                steps_wall.append((time.perf_counter() - w0) / n)
            return n
        sim.advance = timed_advance
        appended = follow_written(service, path, t, q, a.rate)
    lat = []
    for t_step, arrived in hook.arrived.items():
        k = int(np.searchsorted(t, t_step - 1e-9))   # the sample that completed the step
        # the final partial step is taken only at the idle exit: not a following latency
        if 0 < k < t.size - 1:
            lat.append(arrived - appended[k])
    lat = np.array(lat[1:])        # the first step includes start-up
    steps = np.array(steps_wall)
    print(f"{lat.size} alerts from {t.size} lines at {a.rate:g} line/s, poll {a.poll:g} s")
    print(f"latency line appended -> alert handed to the hook: median {np.median(lat) * 1e3:.1f} ms, "
          f"p99 {np.percentile(lat, 99) * 1e3:.1f} ms, max {lat.max() * 1e3:.1f} ms")
    if steps.size:
        print(f"wall time of a model step: median {np.median(steps) * 1e3:.2f} ms "
              f"({steps.size} calls)")



def follow_written(service, path, t, q, rate):
    """Run ``service`` while a writer thread appends the samples (t, q) to ``path`` at ``rate``
    lines per second; returns the wall time (perf_counter) each line was appended."""
    appended = np.zeros(t.size)

    def writer():
        t0 = time.perf_counter()
        with open(path, "a") as fh:
            for k in range(t.size):
                time.sleep(max(0.0, t0 + k / rate - time.perf_counter()))
                fh.write(f"{float(t[k])!r},{float(q[k])!r}\n")
                fh.flush()
                appended[k] = time.perf_counter()

    th = threading.Thread(target=writer)
    th.start()
    service.run()
    th.join()
    return appended


def _log_samples(lines):
    log = read_injection_log(ROOT / "configs" / "logs" / "rustrel-2015-standin.csv")
    t = np.arange(0.0, min(log.duration, lines - 1) + 0.5, 1.0)
    return t, log.rate_at(t)


def step_latencies(a, lookahead):
    """One monitor run following the log as it is written, screened by the scene's rules:
    (step latencies from the append in s, the same from the stage being fed the line in s, the
    forks' (wall, live thread CPU) in s, the live thread's CPU time per step in s, the stage)."""
    scene = Scene.from_toml(ROOT / "configs" / "rustrel-2015-calibrated.toml")
    t, q = _log_samples(a.lines)
    forks, fed = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "live.csv"
        path.write_text("elapsed[s],flow_rate[m3/s]\n")
        cfg = MonitorConfig(follow=str(path), idle_exit=max(3.0, 5 * a.poll + 2.0 / a.rate),
                            poll_interval=a.poll, outbox=Path(tmp) / "box.sqlite",
                            checkpoint_every=10**9, out=Path(tmp) / "live.h5", lookahead=lookahead)
        handed = []
        service = MonitorService(scene, cfg)
        stage = service.stage
        screen_step, feed_samples = stage._screen_step, stage.feed_samples

        def timed_feed(times, *args, **kw):
            w0 = time.perf_counter()
            for sample_time in times:
                fed.setdefault(float(sample_time), w0)
            return feed_samples(times, *args, **kw)
        stage.feed_samples = timed_feed

        def timed_screen_step(row, upd):
            screen_step(row, upd)          # its alerts, had it any, are in the outbox now
            handed.append((float(row["time"]), time.perf_counter()))
        stage._screen_step = timed_screen_step
        la = stage.lookahead
        if la is not None:
            refresh = la.refresh

            def timed_refresh(*args, **kw):
                w0, c0 = time.perf_counter(), time.thread_time()
                started = refresh(*args, **kw)
                if started:
                    forks.append((time.perf_counter() - w0, time.thread_time() - c0))
                return started
            la.refresh = timed_refresh
        cpu0 = time.thread_time()         # (the service runs in this thread: the live thread)
        appended = follow_written(service, path, t, q, a.rate)
        live_cpu = time.thread_time() - cpu0
    lat, from_fed = [], []
    for t_step, wall in handed:
        k = int(np.searchsorted(t, t_step - 1e-9))
        if 0 < k < t.size - 1:
            lat.append(wall - appended[k])
            from_fed.append(wall - fed[float(t[k])])
    steps = max(len(handed), 1)
    return (np.array(lat[1:]), np.array(from_fed[1:]), np.array(forks).reshape(-1, 2),
            live_cpu / steps, service.stage)


def median_difference(with_, without, resamples, seed=1):
    """(median(with_) - median(without), and the 2.5 and 97.5 percentiles of that difference
    over ``resamples`` bootstrap resamples of each, drawn with replacement)."""
    rng = np.random.default_rng(seed)
    a = with_[rng.integers(0, with_.size, (resamples, with_.size))]
    b = without[rng.integers(0, without.size, (resamples, without.size))]
    d = np.median(a, axis=1) - np.median(b, axis=1)
    return float(np.median(with_) - np.median(without)), *np.percentile(d, [2.5, 97.5])


def compare_lookahead(a):
    import os

    plans = a.plan or ["hold", "stop"]
    load = os.getloadavg()[0]
    settings = {"plans": plans, "horizon": a.horizon, "every": a.lookahead_every, "advise": False}
    runs = [("without look-ahead", None),
            (f"with look-ahead ({', '.join(plans)}; {a.horizon:g} s ahead every {a.lookahead_every:g} s)",
             settings)]
    if a.members:
        from fault_screen.calibration import check_keys, load_parameters, sample_parameters

        params = load_parameters(a.vary).select(a.free.split(","))
        check_keys(Scene.from_toml(ROOT / "configs" / "rustrel-2015-calibrated.toml"), params)
        draws = sample_parameters(params, a.members, "normal", a.seed)
        runs.append((f"with the ensemble look-ahead ({a.members} members of {a.free}; the same plans)",
                     dict(settings, ensemble={"draws": draws, "confidence": None})))
    print(f"{a.lines} lines at {a.rate:g} line/s, poll {a.poll:g} s; 2 cores, load average "
          f"{load:.1f} at the start (busy: compare the two rows, not absolute values)")
    print("| run | steps | median (ms) | p95 (ms) | max (ms) | from the stage fed, median (ms) | p95 (ms) "
          "| live thread CPU per step (ms) | forks on the live thread, wall / CPU (ms, median) "
          "| refreshes made / skipped |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    measured = []
    for name, la in runs:
        lat, from_fed, forks, live_cpu, stage = step_latencies(a, la)
        measured.append((name, lat, from_fed))
        fork = (f"{np.median(forks[:, 0]) * 1e3:.2f} / {np.median(forks[:, 1]) * 1e3:.2f}" if forks.size
                else "-")
        made = (f"{stage.lookahead.made} / {stage.lookahead.skipped}" if stage.lookahead is not None
                else "-")
        print(f"| {name} | {lat.size} | {np.median(lat) * 1e3:.1f} | "
              f"{np.percentile(lat, 95) * 1e3:.1f} | {lat.max() * 1e3:.1f} | {np.median(from_fed) * 1e3:.1f} | "
              f"{np.percentile(from_fed, 95) * 1e3:.1f} | {live_cpu * 1e3:.2f} | {fork} | {made} |", flush=True)
    _, lat0, fed0 = measured[0]
    for name, lat, from_fed in measured[1:]:
        parts = []
        for what, x, x0 in (("from the append", lat, lat0), ("from the stage fed", from_fed, fed0)):
            d, lo, hi = median_difference(x, x0, a.bootstrap)
            parts.append(f"{what} {d * 1e3:+.1f} ms [{lo * 1e3:+.1f}, {hi * 1e3:+.1f}]")
        print(f"{name}, median minus the run without (95 % bootstrap interval): {'; '.join(parts)}")


def advice_reuse(a):
    from fault_screen.forecast import LookAhead, advise
    from fault_screen.monitor import Stage
    from fault_screen.monitor.lookahead import LiveLookAhead, LookAheadForecaster
    import os

    class FreshAndReused(LookAheadForecaster):
        """Both bisections on the same look-ahead state; the reused one is kept (as live)."""

        def __init__(self):
            super().__init__(advise=True)
            self.table = []

        def forecast(self, sim_fork, plans, horizon, now_utc, *, screening, drive=None, start=None):
            ahead = LookAhead(sim_fork, screening, drive=drive, start=start)
            c0 = time.thread_time()
            fresh = advise(ahead, horizon, level=self.advise_level)
            c1 = time.thread_time()
            reused = advise(ahead, horizon, level=self.advise_level, near=self.near)
            c2 = time.thread_time()
            self.table.append((ahead.made_at, fresh, c1 - c0, reused, c2 - c1))
            self.last_advice = reused
            return []

    scene = Scene.from_toml(a.scene)
    log = read_injection_log(ROOT / "configs" / "logs" / "rustrel-2015-standin.csv")
    both = FreshAndReused()
    stage = Stage(scene, start=log.start, lookahead=LiveLookAhead(
        plans=["hold"], horizon=a.horizon, every=a.lookahead_every, forecaster=both))
    print(f"{scene.title}: the stand-in log to {a.until:g} s, advice over {a.horizon:g} s "
          f"every {a.lookahead_every:g} s; 2 cores, load average {os.getloadavg()[0]:.1f} at the start "
          f"(CPU time of the worker thread: the work, not the waiting)")
    print("| refresh at (s) | fresh: look-aheads | fresh: CPU (s) | reusing: look-aheads | "
          "reusing: CPU (s) | advised rate (L/min) | relative difference |")
    print("|---|---|---|---|---|---|---|")
    for k in range(log.time.size):
        stage.feed_samples(log.time[k:k + 1], log.flow_rate[k:k + 1])
        stage.wait_forecasts()
        if stage.time >= a.until:
            break
    for made_at, fresh, cpu_fresh, reused, cpu_reused in both.table:
        diff = abs(reused.rate - fresh.rate) / fresh.rate if fresh.rate > 0 else 0.0
        print(f"| {made_at:g} | {fresh.evaluations} | {cpu_fresh:.2f} | {reused.evaluations} | "
              f"{cpu_reused:.2f} | {fresh.rate * 60e3:.4g} / {reused.rate * 60e3:.4g} | {100 * diff:.2f} % |")
    later = both.table[1:]           # the first refresh has nothing to reuse
    if later:
        cpu = np.array([(row[2], row[4]) for row in later])
        print(f"refreshes after the first: CPU time per advice, median {np.median(cpu[:, 0]):.2f} s fresh, "
              f"{np.median(cpu[:, 1]):.2f} s reusing ({np.median(cpu[:, 1] / cpu[:, 0]):.2f} of it); "
              f"largest rate difference {100 * max(abs(r[3].rate - r[1].rate) / r[1].rate for r in later):.2f} %")


def handover(repeat):
    import os
    import queue

    from fault_screen.monitor.lookahead import lower_worker_priority

    def refresh():
        x = np.linspace(0.0, 1.0, 40000).reshape(200, 200)
        return float((x @ x).sum())

    def in_new_thread():
        lower_worker_priority()
        refresh()

    jobs = queue.Queue()

    def waiting_worker():
        lower_worker_priority()
        for done in iter(jobs.get, None):
            refresh()
            done.set()

    threading.Thread(target=waiting_worker, daemon=True).start()
    started, put = [], []
    for _ in range(repeat):
        w = time.perf_counter()
        th = threading.Thread(target=in_new_thread, daemon=True)
        th.start()
        started.append(time.perf_counter() - w)
        th.join()
        done = threading.Event()
        w = time.perf_counter()
        jobs.put(done)
        put.append(time.perf_counter() - w)
        done.wait()
        time.sleep(0.02)
    jobs.put(None)
    print(f"{repeat} refreshes handed over; 2 cores, load average {os.getloadavg()[0]:.1f}")
    print("| handed to | live thread wall, median (ms) | p95 (ms) | max (ms) |")
    print("|---|---|---|---|")
    for name, v in (("a new thread (Thread.start)", started), ("a waiting worker thread (queue put)", put)):
        v = np.array(v) * 1e3
        print(f"| {name} | {np.median(v):.3f} | {np.percentile(v, 95):.3f} | {v.max():.3f} |")


def worker_beside(blocks):
    import os

    from fault_screen import Simulation
    from fault_screen.monitor.lookahead import lower_worker_priority
    from fault_screen.screening.stepwise import StepScreening

    scene = Scene.from_toml(ROOT / "configs" / "rustrel-2015-calibrated.toml")
    sim = Simulation(scene)
    fp = sim.disc.fault_points
    screening = StepScreening.for_scene(scene, fp.s - sim.disc.injection.s, fp.weight)
    screening.screen_simulation(sim)

    def steps(n):
        out = []
        for _ in range(n):
            w, c = time.perf_counter(), time.thread_time()
            sim.advance(sim.time + scene.time.dt, align=True, max_steps=1)
            screening.screen_simulation(sim)
            out.append((time.perf_counter() - w, time.thread_time() - c))
        return out

    def worker(fork, stop, nice):
        if nice:
            lower_worker_priority()
        while not stop.is_set():
            f, n = fork.fork(), 0
            while not stop.is_set() and n < 50 and f.advance(f.time + scene.time.dt, max_steps=1):
                n += 1

    steps(5)
    print(f"live steps of the calibrated Rustrel scene, {blocks} blocks of 10 per case; 2 cores, "
          f"load average {os.getloadavg()[0]:.1f}")
    print("| worker | live step wall, median (ms) | p95 (ms) | live thread CPU per step, median (ms) |")
    print("|---|---|---|---|")
    for nice in (True, False):
        alone, beside = [], []
        for _ in range(blocks):
            alone += steps(10)
            stop = threading.Event()
            th = threading.Thread(target=worker, args=(sim.fork(), stop, nice), daemon=True)
            th.start()
            time.sleep(0.3)
            beside += steps(10)
            stop.set()
            th.join()
        for name, v in (("none", alone), ("nice +10" if nice else "same priority", beside)):
            v = np.array(v)
            print(f"| {name} | {np.median(v[:, 0]) * 1e3:.1f} | {np.percentile(v[:, 0], 95) * 1e3:.1f} | "
                  f"{np.median(v[:, 1]) * 1e3:.1f} |")


if __name__ == "__main__":
    main()
