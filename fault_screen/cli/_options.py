"""Shared options of the ``fault-screen`` commands and the mapping of errors to exit codes.

Exit codes (the only place they are decided):

* 0 -- success;
* 1 -- the run failed (:class:`~fault_screen.SimulationError`), an output could not be written,
  or an unexpected internal error;
* 2 -- bad usage or bad input: unknown option (click), bad scene (:class:`~fault_screen.SceneError`),
  bad injection log (:class:`~fault_screen.io.injection_log.InjectionLogError`), unknown unit,
  missing or unreadable input file, bad event catalogue;
* 3 -- the fault became unstable (the run stopped early; results kept), before any other code;
* 4 -- ``--fail-on LEVEL`` and the screening reached LEVEL (see :mod:`fault_screen.cli._verdict`).

Every error is printed as one line ``Error: ...`` on stderr, without a traceback (set the
environment variable ``FAULT_SCREEN_TRACEBACK=1`` to get one for unexpected errors).
"""
from __future__ import annotations

import contextlib
import gc
import os
from datetime import datetime
from pathlib import Path

import click

from .. import __version__

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_BAD_INPUT = 2
EXIT_UNSTABLE = 3
EXIT_LEVEL_REACHED = 4


class BadInput(click.ClickException):
    """Bad usage or bad input (exit code 2)."""
    exit_code = EXIT_BAD_INPUT


class RunFailed(click.ClickException):
    """The run or an output failed (exit code 1)."""
    exit_code = EXIT_FAILURE


def _describe_os_error(exc: OSError) -> str:
    name = getattr(exc, "filename", None)
    why = exc.strerror or str(exc)
    return f"{name}: {why}" if name else why


@contextlib.contextmanager
def reading(what: str | None = None):
    """Turn any error raised while reading user input into :class:`BadInput` (exit code 2).

    ``what`` (e.g. the file name) prefixes the message unless the message already names it.
    """
    try:
        yield
    except click.ClickException:
        raise
    except FileNotFoundError as exc:
        raise BadInput(f"file not found: {exc.filename or what}") from None
    except IsADirectoryError as exc:
        raise BadInput(f"{exc.filename or what}: is a directory, expected a file") from None
    except OSError as exc:
        msg = _describe_os_error(exc)
        if what and str(what) not in msg:
            msg = f"{what}: {msg}"
        raise BadInput(msg) from None
    except (ValueError, KeyError, TypeError) as exc:
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        if what and str(what) not in msg and Path(str(what)).name not in msg:
            msg = f"{what}: {msg}"
        raise BadInput(msg) from None


def to_exit(exc: BaseException) -> click.ClickException | None:
    """The click exception (message + exit code) for an error escaping a command, or None to
    let it propagate (click's own exceptions, aborts, exits)."""
    if isinstance(exc, (click.ClickException, click.exceptions.Exit, click.Abort,
                        KeyboardInterrupt, SystemExit)):
        return None
    # after click's own exits (--help among them), which need no model imported
    from ..simulate import SimulationError

    if isinstance(exc, SimulationError):
        return RunFailed(f"simulation failed: {exc}")
    from ..scene import SceneError

    if isinstance(exc, SceneError):  # found while building the model (fault geometry, in-situ state)
        return BadInput(str(exc))
    if isinstance(exc, OSError):
        return RunFailed(f"I/O error: {_describe_os_error(exc)}")
    if os.environ.get("FAULT_SCREEN_TRACEBACK"):
        return None
    return RunFailed(f"internal error: {type(exc).__name__}: {exc} "
                     f"(set FAULT_SCREEN_TRACEBACK=1 for a traceback)")


class Group(click.Group):
    """The command group; every error escaping a command goes through :func:`to_exit`."""

    #: whether the process ends with the command: ``main()`` as the console script calls it (the
    #: command line read from sys.argv, click exiting the process); never for a caller that
    #: goes on (a test's CliRunner passes its arguments)
    process_ends = False

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        self.process_ends = args is None and standalone_mode
        try:
            return super().main(args, prog_name, complete_var, standalone_mode, **extra)
        finally:
            if self.process_ends:
                self.process_ends = False
                gc.freeze()     # see leave_to_the_system

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except Exception as exc:  # noqa: BLE001 - mapped to an exit code, one line
            mapped = to_exit(exc)
            if mapped is None:
                raise
            raise mapped from None


def leave_to_the_system() -> None:
    """When the process ends with the command (:attr:`Group.process_ends`), the objects made so
    far (the imported modules' above all: numba's, scipy's) leave the garbage collector's care
    for good (``gc.freeze``): its full collections would walk them all, again and again, for
    objects that live until the process ends and memory the system takes back then. The
    group does it again as the command ends, where the interpreter's last collections took as
    long as loading the kernels (0.5 s of CPU after a bundled run). Files, atexit handlers and
    the modules' teardown are left as they are. In a caller that goes on, nothing."""
    ctx = click.get_current_context(silent=True)
    if ctx is not None and getattr(ctx.find_root().command, "process_ends", False):
        gc.freeze()


# ---- option callbacks ---------------------------------------------------------------------
def _unit_callback(quantity: str):
    def check(ctx, param, value):
        if value is None:
            return None
        from ..units import UnitError, factor

        try:
            factor(value, quantity)
        except UnitError as exc:
            raise BadInput(f"--{param.name.replace('_', '-')} {value!r}: {exc}") from None
        return value
    return check


def parse_iso(text: str, what: str = "--t0") -> datetime:
    """An ISO 8601 timestamp with a time zone (``Z`` accepted) as an aware datetime."""
    txt = text.strip()
    if txt[-1:] in ("Z", "z"):
        txt = txt[:-1] + "+00:00"
    try:
        dt = datetime.fromisoformat(txt)
    except ValueError:
        raise BadInput(f"{what} {text!r}: not an ISO 8601 timestamp "
                       f"(e.g. 2015-03-12T10:00:00+01:00)") from None
    if dt.utcoffset() is None:
        raise BadInput(f"{what} {text!r}: timestamp without time zone (add e.g. +01:00 or Z)")
    return dt


def _t0_callback(ctx, param, value):
    return None if value is None else parse_iso(value, "--t0")


def _positive_callback(ctx, param, value):
    if value is not None and not value > 0:
        raise BadInput(f"--{param.name.replace('_', '-')} {value!r}: must be > 0")
    return value


def version_option(f):
    return click.version_option(__version__, "--version", prog_name="fault-screen",
                                message="%(prog)s %(version)s")(f)


def _compose(*decorators):
    def apply(f):
        for d in reversed(decorators):
            f = d(f)
        return f
    return apply


FILE = click.Path(dir_okay=False, path_type=Path)


class _FileOrUrl(click.ParamType):
    """A file path, or an http(s) URL of a web service kept as text (HYDWS, FDSN event)."""

    name = "file_or_url"

    def convert(self, value, param, ctx):
        if isinstance(value, str) and value.lower().startswith(("http://", "https://")):
            return value
        return FILE.convert(value, param, ctx)


FILE_OR_URL = _FileOrUrl()
DIR = click.Path(file_okay=False, path_type=Path)

out_option = click.option(
    "--out", "-o", type=FILE, default=None, metavar="RESULT.h5",
    help="HDF5 result file to write [default: <scene-stem>.h5 in the current directory].")

def out_dir_option(default: Path | None, help: str):
    """``--out-dir DIR``: the folder a command writes into (``--out`` is always a file). The old
    spelling ``--out``/``-o`` of these commands still works, hidden, with a warning."""
    def old_spelling(ctx, param, value):
        if value is None:
            return None
        if ctx.params.get("out_dir") is not None:
            raise BadInput("--out is the old spelling of --out-dir: give --out-dir only")
        click.echo(f"Warning: --out {value} names a folder here: the option is now --out-dir "
                   f"(--out is always a file); --out will be removed", err=True)
        ctx.meta["fault_screen.out_dir"] = value
        return None

    def new_spelling(ctx, param, value):
        old = ctx.meta.get("fault_screen.out_dir")
        if value is not None and old is not None:
            raise BadInput("--out is the old spelling of --out-dir: give --out-dir only")
        value = value if value is not None else old
        return value if value is not None else default

    return _compose(
        click.option("--out-dir", "out_dir", type=DIR, default=None, metavar="DIR",
                     callback=new_spelling, help=help),
        click.option("--out", "-o", "deprecated_out", type=DIR, default=None, hidden=True,
                     expose_value=False, callback=old_spelling),
    )


set_option = click.option(
    "--set", "sets", multiple=True, metavar="KEY=VALUE",
    help="Change a scene value first, by dotted key in SI (repeatable), e.g. --set mesh.nx=26 "
         "--set time.dt=20.")

events_option = click.option(
    "--events", type=FILE_OR_URL, default=None, metavar="CATALOG|URL",
    help="Seismic event catalogue (QuakeML, CSV or FDSN text) or FDSN event service URL, "
         "drawn on the time axes and stored "
         "under /events; with a [site] table in the scene, distances to the injection point and "
         "to the fault plane.")

t0_option = click.option(
    "--t0", type=str, default=None, metavar="ISO", callback=_t0_callback,
    help="Date-time of model time 0, ISO 8601 with zone (e.g. 2015-03-12T10:00:00+01:00): "
         "reference of the event times. Default: the log's first stamp (replay), the start "
         "stored in the result (plot), else the first event.")

#: options common to ``run`` and ``replay``
run_options = _compose(
    out_option,
    click.option("--plot", "plot_dir", type=DIR, default=None, metavar="DIR",
                 help="Write the figures (PNG) into DIR after a successful run."),
    events_option,
    t0_option,
    click.option("--quiet", "-q", is_flag=True, help="No progress display."),
)

#: how a log's columns are read, for ``replay`` and ``monitor``
log_reading_options = _compose(
    click.option("--time-unit", default=None, metavar="U", callback=_unit_callback("time"),
                 help="Unit of elapsed-time numbers when the header names none (s, min, h, d)."),
    click.option("--volume-column", default=None, metavar="NAME|N",
                 help="A column of the volume injected since the previous row, instead of a "
                      "rate [default: detected when there is no rate column]."),
    click.option("--cumulative-volume-column", default=None, metavar="NAME|N",
                 help="A column of the volume injected since the start, instead of a rate."),
    click.option("--volume-unit", default=None, metavar="U", callback=_unit_callback("volume"),
                 help="Unit of the volume column when its header names none (m3, L, bbl)."),
    click.option("--accept-implausible", is_flag=True,
                 help="Go on with a log that looks like a unit mistake (samples faster than "
                      "any logger, rates or volumes no injection reaches)."),
)


def log_path_option(required: bool = True, help: str = "Injection log (CSV: time + flow rate "
                    "[+ pressure] columns), or the URL of a HYDWS borehole section "
                    "(?starttime=&endtime= for the window)."):
    """``--log LOG|URL``: the injection log that drives a run."""
    return click.option("--log", "log_path", type=FILE_OR_URL, required=required,
                        metavar="LOG|URL", help=help)


#: how ``replay`` reads its ``--log`` and where the run ends (``scene check --log`` too)
log_format_options = _compose(
    click.option("--flow-unit", default=None, metavar="U", callback=_unit_callback("flow_rate"),
                 help="Unit of the flow-rate column when its header has none (e.g. L/min, m3/h)."),
    click.option("--pressure-unit", default=None, metavar="U", callback=_unit_callback("pressure"),
                 help="Unit of the pressure column when its header has none (e.g. MPa, bar, psi)."),
    click.option("--max-gap", type=float, default=600.0, show_default=True, metavar="S",
                 callback=_positive_callback,
                 help="Longest accepted interval between log samples (s); 'inf' disables."),
    click.option("--policy", type=click.Choice(["stop", "skip", "hold"]), default="stop",
                 show_default=True,
                 help="On a bad row or gap: stop with an error, skip the row (gaps bridged "
                      "linearly), or hold the last good value."),
    click.option("--end", type=float, default=None, metavar="S", callback=_positive_callback,
                 help="End time of the run (s after the first stamp) [default: log duration]; "
                      "after the log's last sample the rate is 0 (shut-in), with a warning."),
    click.option("--date", "log_date", default=None, metavar="YYYY-MM-DD",
                 help="Day of the first row of a log whose stamps are times of day (08:50:05); "
                      "a time going back by more than 12 h is the next day."),
    click.option("--tz", "log_tz", default=None, metavar="ZONE",
                 help="Time zone of stamps written without an offset (IANA name: "
                      "Europe/Zurich, America/Denver, UTC)."),
    click.option("--time-column", default=None, metavar="NAME|N",
                 help="The log's time column, by header or 1-based position [default: "
                      "detected]."),
    click.option("--flow-column", default=None, metavar="NAME|N",
                 help="The log's flow-rate column, by header or 1-based position."),
    click.option("--pressure-column", default=None, metavar="NAME|N",
                 help="The log's pressure column, by header or 1-based position."),
    log_reading_options,
)

#: options of ``replay`` that control how the injection log is read
log_options = _compose(log_path_option(), log_format_options)

def check_log(log, scene, accepted: bool) -> None:
    """Stop (exit 2, one line) at a log that looks like a unit mistake, unless ``accepted``;
    warn loudly about what is only unusual."""
    from ..io.plausibility import check_plausible

    rates = [abs(v) for _, v in scene.injection.schedule] if scene.injection.control == "rate" \
        else []
    name = os.path.basename(str(log.source))
    for finding in check_plausible(log.time, log.flow_rate, scene_rate=max(rates, default=None)):
        if finding.level == "stop" and not accepted:
            raise BadInput(f"implausible log {name}: {finding.message}")
        click.echo(f"Warning: IMPLAUSIBLE log {name}: {finding.message}", err=True)


def check_size(scene, label) -> None:
    """Refuse a mesh whose run would not fit in this machine's memory, with the estimate, before
    anything is built (exit 2)."""
    from ..discretisation import estimate_size

    elements, unknowns, need = estimate_size(scene)
    try:
        have = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):   # not POSIX: assume a large workstation
        have = 64e9
    if need > 0.8 * have:
        m = scene.mesh
        mesh = (f"mesh.nx = {m.nx}, mesh.ny = {m.ny}" if m.refinement is None
                else "the graded mesh ([mesh.refinement])")
        raise BadInput(f"{label}: {mesh} gives about {elements:.3g} elements and {unknowns:.3g} "
                       f"unknowns, needing about {need / 1e9:.3g} GB of memory; this machine has "
                       f"{have / 1e9:.3g} GB. Use a coarser mesh or a graded one "
                       f"([mesh.refinement]).")
