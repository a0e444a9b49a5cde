"""Options and progress shared by the commands that run many scenes on the ensemble runner
(calibrate, sensitivity, ensemble, accuracy)."""
from __future__ import annotations

import sys
import time

import click

from ._options import BadInput, RunFailed, _compose, out_dir_option, set_option
from ._progress import format_duration


def _workers_callback(ctx, param, value):
    if value is not None and value < 0:
        raise BadInput(f"--workers {value}: must be >= 0 (0 runs in this process, without Dask)")
    return value


def _scheduler_callback(ctx, param, value):
    if value is not None and "://" not in value:
        raise BadInput(f"--scheduler {value!r}: expected an address like tcp://HOST:PORT")
    return value


runner_options = _compose(
    out_dir_option(None, "Folder for the outputs [default: ./<command>-<scene-stem>]."),
    click.option("--workers", type=int, default=2, show_default=True, callback=_workers_callback,
                 help="Worker processes of the local Dask cluster, one BLAS thread each "
                      "(0: run in this process)."),
    click.option("--scheduler", default=None, metavar="tcp://HOST:PORT", callback=_scheduler_callback,
                 help="Use an existing Dask scheduler instead of a local cluster."),
    click.option("--quiet", "-q", is_flag=True, help="No progress display."),
    set_option,
)


def open_runner(workers: int, scheduler: str | None):
    """A started :class:`~fault_screen.ensemble.Runner`; a scheduler that cannot be reached is
    a failure (exit 1) naming the address."""
    from ..ensemble import Runner

    runner = Runner(workers, scheduler)
    try:
        return runner.__enter__()
    except OSError as exc:
        raise RunFailed(f"--scheduler {scheduler}: cannot connect: {exc}") from None


class TaskBar:
    """``progress(done, total, failed)`` for Runner.run: a redrawn line on a terminal, a plain
    line every 10 % otherwise."""

    def __init__(self, label: str, quiet: bool = False, stream=None):
        self.label, self.quiet = label, quiet
        self.stream = stream or sys.stdout
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.t0 = time.perf_counter()
        self._next = 0.1

    def __call__(self, done, total, failed):
        if self.quiet:
            return
        frac = done / total if total else 1.0
        wall = time.perf_counter() - self.t0
        failed_txt = f", {failed} failed" if failed else ""
        text = f"{self.label}: {done}/{total} runs{failed_txt}, {format_duration(wall)}"
        if self.tty:
            bar = "#" * int(20 * frac)
            self.stream.write(f"\r[{bar:<20}] {text}   ")
            if done == total:
                self.stream.write("\n")
        elif frac + 1e-12 >= self._next or done == total:
            self.stream.write(text + "\n")
            while self._next <= frac + 1e-12:
                self._next += 0.1
        self.stream.flush()
