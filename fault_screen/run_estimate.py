"""What a run will cost before it starts: steps, wall time, result file and peak memory.

Made from the scene alone (a replay's scene already ends at its log's end: ``plan_replay``),
without building the model (:func:`fault_screen.discretisation.estimate_size` counts the
unknowns). The models and their accuracy against measured runs are in the docs
(docs/performance/long-operations.md); in short:

* steps: the scene's step sequence (``time.dt`` growing by ``time.growth`` up to
  ``time.dt_max``) to ``time.end``; step cuts and the contact's step limit only add steps, so
  this is a lower bound;
* file: every step's series row (in whole chunks), the profiles the ``[output]`` table or the
  automatic rule (:func:`fault_screen.outputs.automatic_profile_count`) keeps, the log's
  samples;
* memory: the model's (``estimate_size``), plus the figures' when ``--plot`` is given (the
  results are streamed and read back in bounded pieces, with HDF5's chunk cache limited to
  ``result_stream.CHUNK_CACHE_BYTES`` a dataset, so the run's length does not count);
* wall time: the start-up, a cost per step growing with the unknowns and one per profile
  kept, on an idle machine.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from .discretisation import estimate_size
from .outputs import SCHEMA, automatic_profile_count, automatic_profile_due
from .scene import Scene

#: wall time of a model step (s) ~ STEP_SECONDS + STEP_SECONDS_PER_UNKNOWN_LOG x N log2 N (N
#: unknowns: the factor's work), of each profile kept PROFILE_SECONDS_PER_POINT x fault points
#: (gathered, shuffled, compressed), and of the start-up (imports, cached kernels, the model)
#: START_SECONDS + START_SECONDS_PER_UNKNOWN x N. Fitted to CPU time (what an idle machine's
#: wall time is) with numpy 2.4, numba 0.68: `fault-screen run` of the calibrated Rustrel scene
#: (280 steps of 5 s, every profile kept; its first step alone for the start-up) at 20 x 21,
#: 50 x 51, 100 x 101 and 200 x 201 (N = 2,646 to 123,012: 0.9, 1.8, 7.3 and 27 ms a step,
#: start-up 0.83 to 2.3 s: `python benchmarks/long_operation.py --sizes 20,50,100,200`), the
#: step within 0.9-1.25x of each; the profile's share from the 3-day steady replay at 50 x 51
#: (51,840 steps, 2,198 profiles, 76 s: 1.44 ms a step and 0.39 ms a profile of 200 points)
STEP_SECONDS = 0.34e-3
STEP_SECONDS_PER_UNKNOWN_LOG = 1.09e-8
PROFILE_SECONDS_PER_POINT = 2.0e-6
START_SECONDS = 0.8
START_SECONDS_PER_UNKNOWN = 1.2e-5
#: bytes of a stored profile per raw byte (byte shuffle, then gzip level 1: result_stream), the
#: most of those measured: 0.63 on the bundled Rustrel run, 0.62 on it at 200 x 201, 0.56 on
#: the Basel 2006 replay with every profile kept, 0.40 on a steady day on a 4 x 5 mesh (quiet
#: profiles pack smaller)
PROFILE_COMPRESSION = 0.63
#: rows of a chunk of a (time,) dataset (result_stream: 4,096 rows of 8 bytes); the series are
#: not compressed, so every started chunk takes its full size
SERIES_CHUNK_ROWS = 4096
#: memory the figures add (matplotlib and a figure being drawn), bytes
PLOT_MEMORY = 80e6
#: CPU time the figures add (matplotlib's import, three figures drawn from bounded reads), s:
#: 1.5 s measured on the bundled run (2.9 s with --plot, 1.4 s without)
PLOT_SECONDS = 1.5
#: when the advice says how to thin or coarsen
LARGE_FILE = 1e9
LONG_RUN = 3600.0

#: per-step (time,) datasets of a screened run: /time, injection, balance, solver, screening
_SERIES = sum(1 for o in SCHEMA if o.shape == "(time,)"
              and o.group in ("", "injection", "balance", "solver", "screening"))
#: (time, x) fault profiles
_PROFILES = sum(1 for o in SCHEMA if o.group == "fault" and o.shape == "(time, x)")


@dataclass(frozen=True)
class RunEstimate:
    """A run's cost before it starts (see the module docstring)."""
    steps: int
    """Model steps to the end (a lower bound: cuts add steps) (-)."""
    profiles: int
    """Fault profiles the result keeps (-)."""
    unknowns: int
    """Unknowns of the model (-)."""
    file_bytes: float
    """Size of the result file (bytes)."""
    memory_bytes: float
    """Peak resident memory of the process (bytes)."""
    wall_seconds: float
    """Wall time of the whole command on an idle machine (s)."""

    def lines(self) -> list[str]:
        """What a run will cost, and, when large, how to thin or coarsen it."""
        out = [f"estimate: {self.steps:,} steps, about {_duration(self.wall_seconds)} on an idle "
               f"machine, result file about {_size(self.file_bytes)} ({self.profiles:,} fault "
               f"profiles), peak memory about {_size(self.memory_bytes)}"]
        if self.file_bytes > LARGE_FILE:
            out.append("advice: the result file is large: keep fewer fault profiles with "
                       "[output] profile_interval (e.g. \"1 h\") or profile_every")
        if self.wall_seconds > LONG_RUN:
            out.append("advice: the run is long: let the steps grow ([time] growth = 1.2 and "
                       "dt_max, e.g. 600 s) or coarsen the mesh ([mesh] nx, ny)")
        if self.memory_bytes > LARGE_MEMORY:
            out.append(_MEMORY_ADVICE)
        return out


#: a monitor's result growing faster than this a day (bytes) is large: a month of it is 3 GB
LARGE_DAY = 100e6
#: a model needing more memory than this (bytes) is large
LARGE_MEMORY = 4e9
#: bytes a monitor stores per log sample (/log time, flow rate, pressure)
LOG_SAMPLE_BYTES = 24
#: a day of operation (s)
DAY = 86400.0


@dataclass(frozen=True)
class MonitorEstimate:
    """What a monitor of the scene costs per day of operation (it has no end): its first day at
    the scene's step rule (``time.dt`` growing by ``growth`` to ``dt_max``)."""
    steps_per_day: int
    """Model steps in the first day (-)."""
    step_seconds: float
    """Wall time of a model step on an idle machine (s)."""
    profiles_per_day: int
    """Fault profiles kept in the first day (-); fewer each later day by the automatic rule."""
    file_bytes_per_day: float
    """Growth of the result file in the first day, the log's samples apart (bytes)."""
    memory_bytes: float
    """Peak resident memory of the process (bytes); it does not grow with the days."""

    def lines(self) -> list[str]:
        """What a day of monitoring costs, and, when large, how to thin or coarsen it."""
        out = [f"estimate per day of operation: {self.steps_per_day:,} steps of about "
               f"{self.step_seconds * 1e3:.2g} ms on an idle machine "
               f"({_duration(self.steps_per_day * self.step_seconds)} of computing a day), "
               f"result file growing by about {_size(self.file_bytes_per_day)} a day "
               f"({self.profiles_per_day:,} fault profiles the first day, fewer later; "
               f"{LOG_SAMPLE_BYTES} B per log sample besides), peak memory about "
               f"{_size(self.memory_bytes)}"]
        if self.file_bytes_per_day > LARGE_DAY:
            out.append("advice: the result file grows fast: let the steps grow ([time] growth = "
                       "1.2 and dt_max, e.g. 600 s) or keep fewer fault profiles ([output] "
                       "profile_interval, e.g. \"1 h\")")
        if self.memory_bytes > LARGE_MEMORY:
            out.append(_MEMORY_ADVICE)
        return out


_MEMORY_ADVICE = "advice: the model needs much memory: coarsen the mesh ([mesh] nx, ny)"


def estimate_monitor(scene: Scene) -> MonitorEstimate:
    """The cost of monitoring with ``scene`` per day of operation (:class:`MonitorEstimate`):
    the first day's steps, profiles and file as :func:`estimate_run` counts a run of a day,
    the series' bytes per row (a day's rows do not fill whole chunks, many days do)."""
    import dataclasses

    day = scene.replace(time=dataclasses.replace(scene.time, end=DAY))
    _, unknowns, model_memory = estimate_size(scene)
    steps = step_count(day)
    profiles = profile_count(day, steps)
    file_bytes = 8.0 * _SERIES * steps + _profile_bytes(scene, profiles)
    return MonitorEstimate(steps_per_day=steps, step_seconds=_step_seconds(unknowns),
                           profiles_per_day=profiles, file_bytes_per_day=file_bytes,
                           memory_bytes=model_memory)


def _step_seconds(unknowns: int) -> float:
    return STEP_SECONDS + STEP_SECONDS_PER_UNKNOWN_LOG * unknowns * math.log2(max(unknowns, 2))


def _profile_bytes(scene: Scene, profiles: int) -> float:
    return PROFILE_COMPRESSION * 8.0 * _PROFILES * fault_points(scene) * profiles


def step_count(scene: Scene) -> int:
    """Steps of the scene's step sequence from 0 to ``time.end`` (the last one shortened)."""
    ts = scene.time
    dt, end = ts.dt, ts.end
    dt_max = ts.dt_max if ts.dt_max is not None else dt
    t, n = 0.0, 0
    while dt < dt_max and t + dt < end * (1 - 1e-12):   # the growing steps, one by one
        t, n, dt = t + dt, n + 1, min(dt * ts.growth, dt_max) if ts.growth > 1 else dt_max
    return n + max(1, math.ceil((end - t) / dt * (1 - 1e-12))) if end > t else n


def profile_count(scene: Scene, steps: int) -> int:
    """Profiles kept of ``steps`` steps (the level changes not counted)."""
    rows = steps + 1
    out = scene.output
    if out.profile_every is None and out.profile_interval is None:
        return automatic_profile_count(rows) + (not automatic_profile_due(rows - 1))
    n = 1
    if out.profile_every is not None:
        n += steps // out.profile_every
    if out.profile_interval is not None:
        n += int(scene.time.end // out.profile_interval)
    return min(rows, n + 1)


def estimate_run(scene: Scene, *, plot: bool = False, log_samples: int = 0) -> RunEstimate:
    """The cost of running ``scene`` to its end (``plot``: with figures; ``log_samples``: the
    replayed log's samples, stored with the result)."""
    _, unknowns, model_memory = estimate_size(scene)
    steps = step_count(scene)
    profiles = profile_count(scene, steps)
    chunks = math.ceil((steps + 1) / SERIES_CHUNK_ROWS)
    file_bytes = (8.0 * _SERIES * SERIES_CHUNK_ROWS * chunks + LOG_SAMPLE_BYTES * log_samples
                  + _profile_bytes(scene, profiles))
    memory = model_memory + (PLOT_MEMORY if plot else 0.0)
    wall = (START_SECONDS + START_SECONDS_PER_UNKNOWN * unknowns + steps * _step_seconds(unknowns)
            + profiles * PROFILE_SECONDS_PER_POINT * fault_points(scene)
            + (PLOT_SECONDS if plot else 0.0))
    return RunEstimate(steps=steps, profiles=profiles, unknowns=unknowns, file_bytes=file_bytes,
                       memory_bytes=memory, wall_seconds=wall)


def fault_points(scene: Scene) -> int:
    """Fault Gauss points (columns of the profiles): four per element the fault cuts."""
    from .discretisation import estimate_cut_elements

    return 4 * estimate_cut_elements(scene)


def _size(n: float) -> str:
    for unit, f in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= f:
            return f"{n / f:.3g} {unit}"
    return f"{n:.0f} B"


def _duration(s: float) -> str:
    if s >= 3600:
        return f"{s / 3600:.3g} h"
    return f"{s / 60:.2g} min" if s >= 120 else f"{s:.2g} s" if s < 10 else f"{s:.0f} s"
