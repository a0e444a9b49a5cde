"""The loop behind ``fault-screen monitor``: source -> stage -> outbox -> alert plugins.

One iteration: read the new samples from the source plugin (waiting up to the poll interval),
poll the event catalogue and the waveform archive, feed the stage, store its alerts in the
outbox (which delivers them in a background thread), checkpoint every ``checkpoint_every``
steps.  SIGINT/SIGTERM: checkpoint, write the results so far, stop (exit 0).  No new sample for
``idle_exit`` seconds, or the source has ended (standard input closed): checkpoint, take the
final partial step to the last sample (so the results equal a replay of the log), write the
results, try the pending alerts once more, stop.  The checkpoint is taken before that final
step, so a later restart with a longer log continues exactly as an uninterrupted run.
"""
from __future__ import annotations

import logging
import signal
import threading
import time
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Dict, List, Optional

from ..io.injection_log import InjectionLogError
from ..io.log_stream import LogDecoder
from . import plugins
from .outbox import Outbox
from .event_service import follower_for
from .seismicity import SdsDetector, SeedLinkDetector, Site
from .lookahead import LiveLookAhead, forecast_text
from .stage import LEVELS, Stage

__all__ = ["MonitorConfig", "MonitorService", "MonitorInputError"]

log = logging.getLogger("fault_screen.monitor")

#: wall seconds between flushes of the streamed result file (beside those of the checkpoints)
FLUSH_INTERVAL = 2.0
#: wall seconds a monitor that ends (source ended, idle) waits for the look-ahead refresh that runs
LOOKAHEAD_END_WAIT = 60.0


class MonitorInputError(ValueError):
    """Input the monitor cannot use, found while running (the message names the option)."""


@dataclass
class MonitorConfig:
    """What ``fault-screen monitor`` was asked to do (paths, SI units, seconds)."""

    follow: str                                # log path, or "-" for standard input
    state: Optional[Path] = None               # checkpoint file (HDF5)
    out: Optional[Path] = None                 # result file written at the end
    events: Optional[Path] = None              # QuakeML / FDSN text catalogue or service URL
    waveforms: Optional[Path] = None           # SDS archive root
    seedlink: Optional[str] = None             # SeedLink server HOST:PORT
    seedlink_streams: str = ""                 # NET_STA[:SELECTORS],... (obspy's stream list)
    idle_exit: Optional[float] = None          # s without a new sample -> clean exit
    alerts: List[str] = field(default_factory=list)   # NAME[:CONFIG] specs
    source: Optional[str] = None               # source plugin (default: csv, stdin, hydws)
    poll_interval: float = 0.5
    checkpoint_every: int = 50                 # steps
    outbox: Optional[Path] = None              # default: next to the state file
    flow_unit: Optional[str] = None
    pressure_unit: Optional[str] = None
    max_gap: Optional[float] = 600.0
    policy: str = "stop"
    log_options: dict = field(default_factory=dict)   # date, tz, *_column, option_names
    t0: Optional[datetime] = None              # model time 0 when the log has no stamps
    site: Optional[Site] = None
    sta_lta: dict = field(default_factory=dict)   # SdsDetector options
    drain_timeout: float = 10.0                # s spent on pending alerts at exit
    label: str = ""
    overwrite: bool = False                    # replace an existing --out of an earlier run
    # look-ahead (None: off): plans (texts), horizon and every (s), advise (bool)
    lookahead: Optional[dict] = None


class MonitorService:
    """Run a :class:`Stage` as a service (see the module docstring).

    With ``config.lookahead`` the stage refreshes forecasts in a worker thread
    (:mod:`~fault_screen.monitor.lookahead`); their alerts go to the same outbox, their
    refreshes are collected also while no sample comes, and at the end the refresh that runs
    is waited for (up to ``drain_timeout`` or :data:`LOOKAHEAD_END_WAIT`, the longer; not
    on SIGINT/SIGTERM).  ``forecaster`` replaces the default one.

    ``sinks`` adds alert plugin instances by key besides ``config.alerts`` (used by embedding
    programs and the latency benchmark); ``simulation_class``, ``screener`` and ``metrics`` are
    passed to the stage (defaults: ``fault_screen.Simulation`` and the scene's rules);
    ``on_update(update)`` is called after every batch of samples the stage took.
    """

    def __init__(self, scene, config: MonitorConfig, *, sinks: Optional[Dict[str, object]] = None,
                 simulation_class=None, screener=None, metrics=None,
                 on_update=None, forecaster=None):
        self.scene, self.cfg = scene, config
        self.on_update = on_update
        self._stop = threading.Event()
        self._stop_reason = ""
        resuming = config.state is not None and Path(config.state).exists()
        extra = Stage.saved_extra(config.state) if resuming else {}
        # plugins first: a bad name or option fails before the model is built
        all_sinks = plugins.alert_sinks(config.alerts)
        all_sinks.update(sinks or {})
        lookahead = None
        if config.lookahead is not None:
            lookahead = LiveLookAhead(**config.lookahead, forecaster=forecaster)
        name = config.source or ("stdin" if config.follow == "-" else "hydws" if
                                 config.follow.startswith(("http://", "https://")) else "csv")
        # at once, before the model is built (which takes a while): what is being followed
        log.info("following %s (source %s) with the scene %s; results: %s; state: %s; "
                 "alerts: %s; events: %s", "standard input" if config.follow == "-" else
                 config.follow, name, config.label or "given", config.out or "kept in memory",
                 (f"{config.state} (resumed)" if resuming else config.state) or "none",
                 ", ".join(all_sinks) or "none",
                 ", ".join(str(x) for x in (config.events, config.waveforms, config.seedlink)
                           if x is not None) or "none")
        self.decoder = LogDecoder(config.follow, flow_unit=config.flow_unit,
                                  pressure_unit=config.pressure_unit, max_gap=config.max_gap,
                                  policy=config.policy, **config.log_options,
                                  resume=extra.get("decoder"),
                                  on_warning=lambda m: log.warning("%s", m),
                                  flowback=scene.injection.allow_flowback,
                                  defer_errors=True)
        self.source = plugins.instantiate("source", name, config.follow, decoder=self.decoder,
                                          poll_interval=config.poll_interval,
                                          log=logging.getLogger(f"fault_screen.sources.{name}"))
        if resuming:
            self.stage, _ = Stage.restore(config.state, scene=scene,
                                          simulation_class=simulation_class,
                                          screener=screener, metrics=metrics, site=config.site,
                                          out=config.out, lookahead=lookahead,
                                          on_alert=self._raised)
            log.info("resumed from %s at model time %.6g s (%d steps, %d samples)",
                     config.state, self.stage.time, self.stage.steps, self.stage.samples.count)
        else:
            sim = simulation_class(scene) if simulation_class is not None else None
            if config.out is not None and Path(config.out).exists() and not config.overwrite:
                raise MonitorInputError(f"--out {config.out}: the file exists; give --overwrite to "
                                        f"replace it, or another name")
            # without checkpoints nothing continues the file: written as OUT.part, renamed
            self.stage = Stage(scene, start=config.t0, simulation=sim, screener=screener,
                               metrics=metrics, site=config.site, label=config.label,
                               out=config.out, out_via_temporary=config.state is None,
                               lookahead=lookahead, on_alert=self._raised)
        box = config.outbox
        if box is None and not all_sinks:
            box = ":memory:"           # no alert plugin: nothing to deliver, no file
        elif box is None:
            base = config.state or config.out or Path("fault-screen-monitor")
            box = Path(str(base) + ".outbox.sqlite")
        self.outbox = Outbox(box, all_sinks, log=logging.getLogger("fault_screen.monitor.outbox"))
        log.info("model ready at model time %.6g s; waiting for samples", self.stage.time)
        self._first_sample_logged = False
        self.catalog = None               # a CatalogFollower or an EventServiceFeed
        self.detector: Optional[SdsDetector] = None
        self._detector_state = extra.get("detector")
        self._events_state = extra.get("event_service")    # an event service's feed
        self._last_ckpt = self.stage.steps
        self._last_wave_poll = 0.0
        self._last_flush = time.monotonic()

    def _raised(self, alert: dict) -> None:
        """An alert the stage has just raised: into the outbox at once (its delivery threads
        send it while the stage goes on with the batch)."""
        self.outbox.put(alert)

    # -- signals ----------------------------------------------------------------------------
    def request_stop(self, reason: str = "stop requested") -> None:
        self._stop_reason = reason
        self._stop.set()

    def install_signal_handlers(self) -> None:
        """SIGINT/SIGTERM stop the loop cleanly (checkpoint, results); the previous handlers
        come back when :meth:`run` returns."""
        def handler(signum, frame):
            self.request_stop(signal.Signals(signum).name)
        self._old_handlers = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}

    # -- pieces -----------------------------------------------------------------------------
    def _start_known(self):
        st = self.stage
        if st.start is None and self.decoder.start is not None and st.steps == 0:
            st.start = self.decoder.start
        if st.start is None:
            wanted = [o for o, v in (("--events", self.cfg.events),
                                     ("--waveforms", self.cfg.waveforms),
                                     ("--seedlink", self.cfg.seedlink)) if v is not None]
            if wanted and self.decoder.has_clock is False:
                raise MonitorInputError(
                    f"{' and '.join(wanted)} need the date-time of model time 0, and the log "
                    f"{self.cfg.follow} has elapsed times: give it with --t0")
            return
        if self.cfg.events is not None and self.catalog is None:
            site = st.site.spec if st.site is not None else None
            self.catalog = follower_for(self.cfg.events, st.start, site=site)
            if self._events_state and hasattr(self.catalog, "restore"):
                self.catalog.restore(self._events_state)
        if self.detector is None and (self.cfg.waveforms is not None or self.cfg.seedlink is not None):
            if self.cfg.seedlink is not None:
                # the same STA/LTA path on the records a SeedLink server streams
                self.detector = SeedLinkDetector(self.cfg.seedlink, self.cfg.seedlink_streams,
                                                 st.start, **self.cfg.sta_lta)
            else:
                self.detector = SdsDetector(self.cfg.waveforms, st.start, **self.cfg.sta_lta)
            if self._detector_state:
                self.detector.restore(self._detector_state)

    def _poll_seismicity(self, force: bool = False) -> None:
        if self.catalog is not None:
            new = self.catalog.poll()
            # an event service's revised and deleted events are forgotten (the revised come again)
            self.stage.withdraw_events(getattr(self.catalog, "take_withdrawn", list)())
            if new:
                log.info("%d new event(s) from %s", len(new), self.cfg.events)
                self.stage.feed_events(new)
        now = time.monotonic()
        if self.detector is not None and self.stage.last_sample_time is not None and (
                force or now - self._last_wave_poll >= max(5 * self.cfg.poll_interval, 1.0)):
            self._last_wave_poll = now
            dets = self.detector.poll(self.stage.last_sample_time)
            if dets:
                log.info("%d STA/LTA detection(s)", len(dets))
                self.stage.feed_events(dets)

    def _feed(self, samples) -> None:
        if samples:
            if not self._first_sample_logged:
                first = samples[0]
                log.info("first sample%s: model time %.6g s, flow rate %.6g m3/s%s (%d in this "
                         "read)", " after the restart" if self.stage.samples.count else "",
                         first.time, first.flow_rate, "" if first.pressure is None else
                         f", pressure {first.pressure:.6g} Pa", len(samples))
                self._first_sample_logged = True
            self._start_known()
            self._poll_seismicity()
            upd = self.stage.feed_samples([s.time for s in samples],
                                          [s.flow_rate for s in samples],
                                          [s.pressure for s in samples])
            self._handle(upd)
        if self.decoder.error is not None:
            # the bad line stops the run after the good samples before it are modelled
            raise self.decoder.error

    def _handle(self, upd, checkpoint: bool = True) -> None:
        # (the alerts went to the outbox as the stage raised them: _raised)
        for d, alert in zip(upd.transitions, upd.alerts):
            log.warning("t = %.6g s: level %s -> %s (%s)%s", d["time"], alert["previous_level"],
                        alert["level"], alert["rule"],
                        f": {alert['action']}" if alert["action"] else "")
        for alert in upd.forecast_alerts:
            log.warning("t = %.6g s: %s", alert["model_time"], alert["text"])
        if upd.forecasts and not upd.forecast_alerts:
            la = self.stage.lookahead
            log.info("t = %.6g s: %s", upd.forecasts[-1]["made_at"],
                     forecast_text(_last_refresh(upd.forecasts), self.stage.start,
                                   la.advise_level, la.confidence))
        if self.on_update is not None:
            self.on_update(upd)
        now = time.monotonic()
        if now - self._last_flush >= FLUSH_INTERVAL:
            self.stage.flush()            # a reader of --out sees the newest steps
            self._last_flush = now
        if checkpoint and self.cfg.state is not None and self.stage.steps - self._last_ckpt >= \
                self.cfg.checkpoint_every:
            self.checkpoint()

    def checkpoint(self) -> None:
        if self.cfg.state is None:
            return
        extra = {"decoder": self.decoder.state(), "outbox_position": self.outbox.count(),
                 "detector": self.detector.state() if self.detector else self._detector_state,
                 "event_service": (self.catalog.state() if hasattr(self.catalog, "state")
                                   else self._events_state)}
        self.stage.checkpoint(self.cfg.state, extra=extra)
        self._last_ckpt = self.stage.steps

    def _write_result(self) -> None:
        if self.stage.out is not None:
            if self.stage.close() is not None:
                log.info("results completed in %s", self.cfg.out)
            return
        if self.cfg.out is not None and self.stage.steps > 0:
            self.stage.result().save(self.cfg.out)
            log.info("results written to %s", self.cfg.out)

    # -- the loop ---------------------------------------------------------------------------
    def run(self) -> dict:
        """Follow the source until stopped; returns a summary dict."""
        self.outbox.start()
        last_data = time.monotonic()
        try:
            try:
                ended = self._loop(last_data)
            except (InjectionLogError, MonitorInputError):
                self.checkpoint()      # the samples before the bad line are kept
                self._write_result()
                raise
        finally:
            left = self.outbox.drain(self.cfg.drain_timeout)
            if left:
                log.warning("%d alert deliveries pending in %s; they are retried at the next "
                            "start", left, self.outbox.path)
            dead = self.outbox.dead()
            if dead:
                log.error("%d alert deliveries refused for good (dead letters in %s; "
                          "'fault-screen plugins --outbox %s' lists them)", dead,
                          self.outbox.path, self.outbox.path)
            self.outbox.close()
            self.source.close()
            if hasattr(self.detector, "close"):
                self.detector.close()
            for signum, old in getattr(self, "_old_handlers", {}).items():
                signal.signal(signum, old)
        st = self.stage
        return {"ended": ended, "steps": st.steps, "time": st.time, "samples": st.samples.count,
                "level": LEVELS[st.level] if 0 <= st.level < len(LEVELS) else st.level,
                "alerts": st.alerts_raised, "pending_alerts": left, "dead_alerts": dead,
                "outbox": str(self.outbox.path)}

    def _loop(self, last_data: float) -> str:
        ended = "stopped"
        while not self._stop.is_set():
            samples = self.source.read(self.cfg.poll_interval)
            if samples:
                self._feed(samples)
                last_data = time.monotonic()     # idle time counts from the end of the work
            else:
                self._poll_seismicity()
                self._feed(samples)              # raises a bad line's error kept meanwhile
                if self.stage.lookahead is not None:
                    self._handle(self.stage.poll_forecasts(), checkpoint=False)
            if getattr(self.source, "finished", False):
                ended = "source ended"
                break
            if self.cfg.idle_exit is not None and \
                    time.monotonic() - last_data >= self.cfg.idle_exit:
                ended = f"no new sample for {self.cfg.idle_exit:g} s"
                break
        if self._stop.is_set():
            ended = self._stop_reason
            self.checkpoint()
            self._write_result()
        else:
            self._feed(self.source.read(0.0))    # what came in meanwhile
            self._feed(self.source.flush())
            self._feed(self.decoder.end())
            self._poll_seismicity(force=True)
            if self.stage.lookahead is not None:      # the refresh that runs, if any
                self._handle(self.stage.wait_forecasts(max(self.cfg.drain_timeout, LOOKAHEAD_END_WAIT)),
                             checkpoint=False)
                if self.stage.lookahead.busy:
                    log.warning("the look-ahead made at t = %.6g s was still running after %g s: "
                                "not stored", self.stage.lookahead.running_since,
                                max(self.cfg.drain_timeout, LOOKAHEAD_END_WAIT))
            self.checkpoint()            # the aligned state: a restart continues from here
            self._handle(self.stage.finish(), checkpoint=False)
            self._write_result()
        return ended


def _last_refresh(rows: list) -> list:
    """The rows of the newest refresh among ``rows`` (those made at the last ``made_at``)."""
    last = rows[-1]["made_at"]
    return [r for r in rows if r["made_at"] == last]
