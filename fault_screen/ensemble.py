"""Run many scene variants as tasks on Dask and stream their summaries into one HDF5 file.

A *variant* is a base scene plus overrides named by dotted scene keys
(``{"injection.number_of_fractures": 46, "rock.youngs_modulus": 12.8e9}``, SI values). Each task
runs in a worker process of a ``distributed.LocalCluster`` (one BLAS thread each, so N workers
use N cores) or of an existing cluster (``scheduler="tcp://host:8786"``), and returns a small
summary computed in the worker by a picklable ``summarise(result) -> dict`` function. A task
that fails is recorded with its parameters and its error, never dropped.

This module sits above the core (it calls ``simulate``) and below the command line; it reads
no scene files itself.
"""
from __future__ import annotations

import dataclasses
import json
import os
import threading
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np

from .physics import switches_implied_by
from .scene import Scene, SceneError

#: environment of every local worker: one BLAS / OpenMP thread, so N workers use N cores
WORKER_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
              "NUMBA_NUM_THREADS": "1"}

#: Dask settings of every local worker, on top of the user's: no statistical profiler (it walks
#: the task thread's stack every 10 ms on the worker's event loop), a slower event-loop tick (a
#: check for a blocked loop, every 20 ms by default) and slower system and memory monitors (the
#: dashboard's figures; the worker's own spill and pause checks, while the nanny still ends a
#: worker over its memory limit at its own pace): together an eighth to a fifth of a task's CPU
#: on the Rustrel scenes with the defaults (benchmarks/forecast_ensemble.py gives the other
#: threads' share). And glibc's own memory thresholds: Dask's nanny starts its workers with
#: MALLOC_TRIM_THRESHOLD_=64 kB, which also fixes glibc's mmap threshold at 128 kB, so every
#: array of a step above that size is mapped and unmapped afresh (page faults, the heap trimmed
#: at every free): a member of the SI Rustrel scene took a fifth to a quarter more CPU, nearly
#: all of it in the kernel (benchmarks/forecast_ensemble.py --malloc-ab); None leaves the
#: variable unset (Dask's way of removing one), so the heap reuses what a step frees
WORKER_CONFIG = {"distributed": {"worker": {"profile": {"enabled": False},
                                            "memory": {"monitor-interval": "1s"}},
                                 "admin": {"tick": {"interval": "500ms"},
                                           "system-monitor": {"interval": "2s"}},
                                 "nanny": {"pre-spawn-environ": {"MALLOC_TRIM_THRESHOLD_": None}}}}


def _dotted(config: dict, prefix: str = "") -> dict:
    """A nested Dask configuration as dotted keys (``dask.config.set`` replaces whole
    sections given nested, these keys only)."""
    out = {}
    for key, value in config.items():
        out.update(_dotted(value, f"{prefix}{key}.") if isinstance(value, dict) else {prefix + key: value})
    return out


# ---- scene variants -------------------------------------------------------------------------
def scene_with(scene: Scene, overrides: dict) -> Scene:
    """``scene`` with values replaced by dotted keys (SI), validated.

    ``fault.rate_parameter = 0`` switches rate friction off and ``fault.dilation_angle = 0``
    switches dilation off (the paper's lower bounds of a and the dilation angle are zero, which
    the scene otherwise refuses as an inconsistent switch)."""
    data = scene.to_dict()
    for key, value in overrides.items():
        parts = key.split(".")
        node, cls = data, type(scene)
        for i, part in enumerate(parts):
            names = {f.name: f for f in dataclasses.fields(cls)}
            if part not in names:
                where = ".".join(parts[:i]) or "scene"
                raise SceneError(f"unknown scene key {key!r}: [{where}] has no {part!r}; "
                                 f"known: {', '.join(sorted(names))}")
            if i == len(parts) - 1:
                node[part] = _plain(value)
                if part == "mobility":
                    node.pop("permeability", None)
                elif part == "permeability":
                    node.pop("mobility", None)
            else:
                cls = _section_class(names[part].type, key)
                node = node.setdefault(part, {})
    data.setdefault("effects", {}).update(switches_implied_by(data.get("fault", {})))
    return Scene.from_dict(data)


def _section_class(hint, key):
    from . import scene as scene_module

    name = str(hint).replace(" | None", "")
    cls = scene_module._SECTIONS.get(name)
    if cls is None:
        raise SceneError(f"scene key {key!r} does not name a single value")
    return cls


def _plain(value):
    if isinstance(value, np.generic):
        return value.item()
    return value


# ---- what a task returns ------------------------------------------------------------------------
def default_summary(result) -> dict:
    """The screened numbers of one run (SI): peak injection overpressure (Pa), slip at the
    injection point at the end and its peak (m), peak slip on the fault (m), slipping length at
    the end (m), peak slip rate (m/s), and the run's cost."""
    inj = result.injection
    slip = np.abs(result.fault["slip"])
    state = result.fault["contact_state"]
    w = result.fault_weights
    return {
        "peak_overpressure": float(np.max(inj["overpressure"])),
        "injection_slip": float(abs(inj["slip"][-1])),
        "peak_injection_slip": float(np.max(np.abs(inj["slip"]))),
        "peak_fault_slip": float(slip.max()) if slip.size else 0.0,
        "slipping_length": float(np.sum(w[state[-1] == 1])) if state.size else 0.0,
        "peak_slip_rate": float(np.max(np.abs(result.fault["slip_rate"]))) if slip.size else 0.0,
        "slip_onset": slip_onset(result),
        **screening_summary(result),
        "steps": int(len(result.time) - 1),
        "newton_iterations": int(np.sum(result.solver["iterations"])),
        "unknowns": int(result.meta.get("dofs", 0)),
    }


def slip_onset(result) -> float:
    """First time the fault slips (contact state 1) at the injection point (s); NaN if never."""
    state = result.fault["contact_state"]
    if not state.size:
        return float("nan")
    hit = np.flatnonzero(state[:, int(np.argmin(np.abs(result.fault_x)))] == 1)
    return float(result.time[hit[0]]) if hit.size else float("nan")


def screening_summary(result) -> dict:
    """From the screening layer (the scene's ``[monitor]`` rules): time the traffic light first
    reached yellow and red (s; NaN if never) and the peak utilisation |tau| / (mu0 sigma'_n) (-)."""
    from .screening import RED, YELLOW, screen_result

    arrays = (result.extra or {}).get("screening")
    if arrays is None or "level" not in arrays:
        arrays = screen_result(result, store=False).arrays()
    level = np.asarray(arrays["level"])
    first = lambda lv: float(result.time[np.argmax(level >= lv)]) if np.any(level >= lv) else float("nan")
    util = np.asarray(arrays.get("max_utilisation", [np.nan]), dtype=float)
    return {"time_first_yellow": first(YELLOW), "time_first_red": first(RED),
            "max_utilisation": float(np.nanmax(util)) if np.isfinite(util).any() else float("nan")}


@dataclass
class TaskOutcome:
    index: int
    name: str
    params: dict
    ok: bool
    summary: dict = field(default_factory=dict)
    error: str = ""
    wall_s: float = float("nan")
    """Wall time of the simulation in the worker, scene building included (s)."""
    peak_memory_mb: float = float("nan")
    """Peak resident memory of the worker during the task above its level before it (MB)."""


class _PeakRSS:
    """Samples the process's resident memory every few milliseconds while a task runs."""

    def __init__(self, every=0.01):
        import psutil

        self.proc = psutil.Process()
        self.base = self.peak = self.proc.memory_info().rss
        self.every = every
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self):
        while not self._stop.wait(self.every):
            self.peak = max(self.peak, self.proc.memory_info().rss)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self.peak = max(self.peak, self.proc.memory_info().rss)

    @property
    def mb(self):
        return (self.peak - self.base) / 2**20


def run_task(index: int, name: str, scene_dict: dict, overrides: dict, summarise: Callable,
             warm: bool = False) -> TaskOutcome:
    """One variant, run where it is called (in a worker, or in-process). Never raises: a failure
    comes back as ``ok=False`` with the error. ``warm``: run the scene once before timing it
    (wall time without JIT compilation or first-touch costs)."""
    from .api import simulate  # screens the result with the scene's [monitor] rules

    outcome = TaskOutcome(index=index, name=name, params=dict(overrides), ok=False)
    try:
        scene = scene_with(Scene.from_dict(scene_dict), overrides)
        if warm:
            simulate(scene.replace(time=dataclasses.replace(scene.time, end=scene.time.dt)))
        with _PeakRSS() as mem:
            t0 = time.perf_counter()
            result = simulate(scene)
            outcome.wall_s = time.perf_counter() - t0
        outcome.peak_memory_mb = mem.mb
        outcome.summary = summarise(result)
        outcome.ok = True
    except Exception as exc:  # recorded, with the parameters, never dropped
        outcome.error = f"{type(exc).__name__}: {exc}"
        if os.environ.get("FAULT_SCREEN_TRACEBACK"):
            outcome.error += "\n" + traceback.format_exc()
    return outcome


# ---- the HDF5 stream ----------------------------------------------------------------------------
class _Stream:
    """One HDF5 file: ``/tasks/<index>`` per finished task (attrs name, ok, error, wall_s,
    peak_memory_mb, params as JSON; datasets: the summary's entries). Flushed after each task,
    so a run cut short keeps what finished."""

    def __init__(self, path, meta: dict):
        import h5py

        self.path = Path(path)
        self.h5 = h5py.File(self.path, "w")
        self.h5.attrs["meta"] = json.dumps(meta, default=str)
        self.h5.create_group("tasks")

    def write(self, o: TaskOutcome):
        g = self.h5["tasks"].create_group(f"{o.index:06d}")
        g.attrs["name"] = o.name
        g.attrs["ok"] = o.ok
        g.attrs["error"] = o.error
        g.attrs["wall_s"] = o.wall_s
        g.attrs["peak_memory_mb"] = o.peak_memory_mb
        g.attrs["params"] = json.dumps(o.params, default=float)
        for k, v in o.summary.items():
            g.create_dataset(k, data=np.asarray(v))
        self.h5.flush()

    def close(self):
        self.h5.close()


def read_ensemble(path) -> list[TaskOutcome]:
    """The outcomes stored by :func:`run_ensemble`, in task order."""
    import h5py

    out = []
    with h5py.File(path, "r") as h5:
        for key in sorted(h5["tasks"]):
            g = h5["tasks"][key]
            summary = {k: (g[k][()].item() if g[k].ndim == 0 else g[k][()]) for k in g}
            out.append(TaskOutcome(index=int(key), name=str(g.attrs["name"]),
                                   params=json.loads(g.attrs["params"]), ok=bool(g.attrs["ok"]),
                                   summary=summary, error=str(g.attrs["error"]),
                                   wall_s=float(g.attrs["wall_s"]),
                                   peak_memory_mb=float(g.attrs["peak_memory_mb"])))
    return out


# ---- the runner -------------------------------------------------------------------------------
@dataclass
class Variant:
    """A named set of dotted-key overrides of the base scene (SI values)."""
    name: str
    overrides: dict
    scene: Scene | None = None
    """A whole scene instead of the base (e.g. another mesh); overrides then apply to it."""


def local_cluster(workers: int):
    """A ``distributed.LocalCluster`` of ``workers`` processes with one thread and one BLAS
    thread each, and :data:`WORKER_CONFIG`, for the workers and for the servers the cluster runs
    in this process (the scheduler and the workers' nannies read this process's settings when
    they start: with Dask's defaults their ticks and memory monitors took a few times the CPU of
    the workers' own machinery, on the cores the members need). The numba cache is the package's own
    (``__pycache__``) unless NUMBA_CACHE_DIR is set, which the workers inherit: either way every
    worker shares one compiled cache."""
    import dask
    from distributed import LocalCluster

    env = dict(WORKER_ENV)
    if "NUMBA_CACHE_DIR" in os.environ:
        env["NUMBA_CACHE_DIR"] = os.environ["NUMBA_CACHE_DIR"]
    with dask.config.set(_dotted(WORKER_CONFIG)):   # (this process's own settings as they were after)
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, env=env,
                            config=dask.config.merge(dask.config.config, WORKER_CONFIG),  # (the nanny's
                            # own merge keeps whole sections: the user's settings merged in here)
                            dashboard_address="127.0.0.1:0", silence_logs=40)  # any free local port


class Runner:
    """Where tasks run: a local cluster of ``workers`` processes (the default), an existing
    Dask scheduler (``scheduler="tcp://host:port"``), or this process (``workers=0``, no Dask).
    Use as a context manager; one runner serves many batches (a calibration's Jacobians)."""

    def __init__(self, workers: int = 1, scheduler: str | None = None):
        if workers < 0:
            raise ValueError(f"workers = {workers}: must be >= 0")
        self.workers, self.scheduler = workers, scheduler
        self.client = self.cluster = None

    def __enter__(self):
        if self.scheduler is not None or self.workers > 0:
            from distributed import Client

            if self.scheduler is None:
                self.cluster = local_cluster(self.workers)
            try:
                self.client = Client(self.scheduler or self.cluster, timeout="30s")
            except Exception:
                self.close()
                raise
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        if self.client is not None:
            self.client.close()
            self.client = None
        if self.cluster is not None:
            self.cluster.close()
            self.cluster = None

    def run(self, base: Scene, variants: Sequence[Variant], *, summarise: Callable = default_summary,
            out=None, progress: Callable[[int, int, int], None] | None = None, warm: bool = False,
            meta: dict | None = None) -> list[TaskOutcome]:
        """Run every variant; return the outcomes in the variants' order. ``out``: HDF5 file the
        outcomes stream into as they finish; ``progress(done, total, failed)`` after each one;
        ``summarise`` must be picklable (a module-level function)."""
        variants = list(variants)
        base_dict = base.to_dict()
        stream = _Stream(out, {"scene": base.title, "tasks": len(variants), **(meta or {})}) if out else None
        outcomes: list[TaskOutcome | None] = [None] * len(variants)
        failed = 0

        def done(o: TaskOutcome):
            nonlocal failed
            outcomes[o.index] = o
            failed += not o.ok
            if stream is not None:
                stream.write(o)
            if progress is not None:
                progress(sum(x is not None for x in outcomes), len(variants), failed)

        def args(i, v):
            return (i, v.name, v.scene.to_dict() if v.scene is not None else base_dict, v.overrides,
                    summarise, warm)

        try:
            for i, o in self.each(run_task, [args(i, v) for i, v in enumerate(variants)]):
                if isinstance(o, BaseException):  # the worker died: record the task anyway
                    o = TaskOutcome(index=i, name=variants[i].name, params=variants[i].overrides,
                                    ok=False, error=f"worker lost: {type(o).__name__}: {o}")
                done(o)
        finally:
            if stream is not None:
                stream.close()
        return [o for o in outcomes if o is not None]

    def each(self, task: Callable, calls: Sequence[tuple]):
        """Yield ``(i, task(*calls[i]))`` as the calls finish (in this process: in order); a
        call whose worker died yields its exception instead. ``task``: a picklable, module-level
        function that does not raise (it reports its own failures)."""
        if self.client is None:
            for i, call in enumerate(calls):
                yield i, task(*call)
            return
        from distributed import as_completed

        futures = [self.client.submit(task, *call, pure=False) for call in calls]
        where = {f.key: i for i, f in enumerate(futures)}
        for fut in as_completed(futures):
            try:
                out = fut.result()
            except Exception as exc:
                out = exc
            yield where[fut.key], out


def run_ensemble(base: Scene, variants: Sequence[Variant], *, workers: int = 1,
                 scheduler: str | None = None, **kwargs) -> list[TaskOutcome]:
    """Run every variant as a task on a fresh :class:`Runner` (see ``Runner.run`` for the
    keyword arguments); ``workers=0`` runs in this process without Dask."""
    with Runner(workers, scheduler) as runner:
        return runner.run(base, variants, **kwargs)


#: event -> the summary entry whose finite value (a time, s) says the run reached it
REACHED = {"slip": "slip_onset", "yellow": "time_first_yellow", "red": "time_first_red"}


def reach_probabilities(outcomes: Iterable[TaskOutcome]) -> dict:
    """Over the successful runs: event (the fault slips at the injection point, the traffic light
    reaches yellow, reaches red) -> (fraction of runs that reached it, half-width of its 95 %
    interval by the normal approximation, 1.96 sqrt(p (1 - p) / n); NaN for one run)."""
    ok = [o for o in outcomes if o.ok]
    n = len(ok)
    out = {}
    for event, key in REACHED.items():
        p = float(np.mean([np.isfinite(o.summary.get(key, np.nan)) for o in ok])) if n else float("nan")
        out[event] = (p, 1.96 * float(np.sqrt(p * (1 - p) / n)) if n > 1 else float("nan"))
    return out


def throughput(outcomes: Iterable[TaskOutcome], elapsed_s: float) -> float:
    """Finished runs per minute over an elapsed wall time."""
    n = sum(1 for _ in outcomes)
    return 60.0 * n / elapsed_s if elapsed_s > 0 else float("nan")
