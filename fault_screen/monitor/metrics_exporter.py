"""Prometheus exposition of a running monitor (``fault-screen monitor --metrics-port PORT``).

Served at ``http://ADDRESS:PORT/metrics`` by the official client library (prometheus-client),
bound to 127.0.0.1 unless another address is given.  Names follow the Prometheus conventions:
the ``fault_screen_`` prefix, base SI units in the name, ``_total`` for counters.

==============================================  ===============================================
``fault_screen_level``                           traffic light: 0 green, 1 yellow, 2 red
``fault_screen_<metric>_<unit>``                 each screening metric of the newest step
                                                 (:data:`SCREENING`; NaN when undefined, e.g.
                                                 no event in the step)
``fault_screen_forecast_time_to_yellow_seconds`` model time left before the forecast of the
``fault_screen_forecast_time_to_red_seconds``    first ``--plan`` reaches yellow / red (NaN: no
                                                 look-ahead yet, or not within its horizon)
``fault_screen_forecast_p_yellow``               the ensemble's probability that the first
``fault_screen_forecast_p_red``                  ``--plan`` reaches yellow / red within the
                                                 horizon (NaN: no ensemble, ``--members``)
``fault_screen_model_time_seconds``              model time of the newest step
``fault_screen_model_lag_seconds``               newest sample's time minus the model time
``fault_screen_step_wall_seconds``               histogram of the wall time of each step
``fault_screen_samples_received_total``          injection samples received
``fault_screen_events_received``                 seismic events and detections held (a revised
                                                 event counts once, a deleted one no more)
``fault_screen_alerts_pending``                  alert deliveries waiting in the outbox
``fault_screen_alerts_dead_letters``             alert deliveries refused for good (dead letters)
``fault_screen_info``                            scene title and fault_screen version
==============================================  ===============================================

The exporter is fed by the service's per-batch hook (``MonitorService(on_update=...)``) with
the stage's :class:`~fault_screen.monitor.stage.Update` (metrics and wall time of each step).
"""
from __future__ import annotations

import math
from typing import Optional

__all__ = ["MetricsExporter", "SCREENING", "metric_name"]

#: screening metric -> (Prometheus unit suffix, factor from the metric's unit to that base unit)
SCREENING = {
    "peak_slip_rate": ("meters_per_second", 1.0),
    "x_peak_slip_rate": ("meters", 1.0),
    "slipping_length": ("meters", 1.0),
    "max_utilisation": ("ratio", 1.0),
    "min_coulomb_margin": ("pascals", 1.0),
    "delta_cff": ("pascals", 1.0),
    "injection_overpressure": ("pascals", 1.0),
    "induced_slip": ("meters", 1.0),
    "event_magnitude": ("", 1.0),                 # a magnitude has no unit
    "event_distance": ("meters", 1.0),
    "event_rate": ("per_second", 1.0 / 3600.0),   # the screening metric counts per hour
}

#: histogram buckets of the step wall time (s)
STEP_BUCKETS = (0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0, 30.0)


def metric_name(metric: str) -> str:
    """Prometheus name of a screening metric (``fault_screen_peak_slip_rate_meters_per_second``)."""
    unit = SCREENING[metric][0]
    return f"fault_screen_{metric}" + (f"_{unit}" if unit else "")


class MetricsExporter:
    """The monitor's metrics in their own registry, served by :meth:`start`."""

    def __init__(self, scene=None, *, registry=None):
        from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, Info

        from .. import __version__

        self.registry = registry if registry is not None else CollectorRegistry()
        r = self.registry
        self.level = Gauge("fault_screen_level", "Traffic light: 0 green, 1 yellow, 2 red",
                           registry=r)
        self.screening = {m: Gauge(metric_name(m), f"Screening metric {m} of the newest step",
                                   registry=r) for m in SCREENING}
        self.time_to_yellow = Gauge("fault_screen_forecast_time_to_yellow_seconds",
                                    "Model time until the forecast turns yellow (NaN: no "
                                    "look-ahead)", registry=r)
        self.time_to_red = Gauge("fault_screen_forecast_time_to_red_seconds",
                                 "Model time until the forecast turns red (NaN: no look-ahead)",
                                 registry=r)
        self.p_yellow = Gauge("fault_screen_forecast_p_yellow",
                              "Fraction of the ensemble's members whose forecast reaches yellow "
                              "within the horizon (NaN: no ensemble)", registry=r)
        self.p_red = Gauge("fault_screen_forecast_p_red",
                           "Fraction of the ensemble's members whose forecast reaches red "
                           "within the horizon (NaN: no ensemble)", registry=r)
        self.model_time = Gauge("fault_screen_model_time_seconds", "Model time of the newest step",
                                registry=r)
        self.model_lag = Gauge("fault_screen_model_lag_seconds",
                               "Time of the newest sample minus the model time", registry=r)
        self.step_wall = Histogram("fault_screen_step_wall_seconds", "Wall time of each step",
                                   buckets=STEP_BUCKETS, registry=r)
        self.samples = Counter("fault_screen_samples_received", "Injection samples received",
                               registry=r)
        self.events = Gauge("fault_screen_events_received",
                            "Seismic events and detections held (revised ones once)", registry=r)
        self.pending = Gauge("fault_screen_alerts_pending",
                             "Alert deliveries waiting in the outbox", registry=r)
        self.dead = Gauge("fault_screen_alerts_dead_letters",
                          "Alert deliveries refused for good by their receiver (dead letters)",
                          registry=r)
        self.info = Info("fault_screen", "The scene followed and the program", registry=r)
        self.info.info({"scene_title": str(getattr(scene, "title", "")), "version": __version__})
        for g in (*self.screening.values(), self.time_to_yellow, self.time_to_red, self.p_yellow,
                  self.p_red, self.model_time, self.model_lag):
            g.set(math.nan)
        self.service = None
        self._samples_seen = 0
        self._server = None

    # -- feeding ------------------------------------------------------------------------------
    def attach(self, service) -> None:
        """Read the sample count, events and outbox of this MonitorService at each update."""
        self.service = service

    def update(self, upd) -> None:
        """Take one :class:`~fault_screen.monitor.stage.Update` (the service's on_update hook)."""
        for seconds in getattr(upd, "step_seconds", ()):
            self.step_wall.observe(seconds)
        self.level.set(upd.level)
        if upd.state is not None:
            self.model_time.set(float(upd.state["time"]))
        for m, gauge in self.screening.items():
            if m in upd.metrics:
                v = upd.metrics[m]
                gauge.set(math.nan if v is None else float(v) * SCREENING[m][1])
        forecasts = getattr(upd, "forecasts", ())
        if forecasts:
            # each refresh's rows begin with the plan followed: its newest row
            lead = forecasts[0]["plan"]
            row = [r for r in forecasts if r["plan"] == lead][-1]
            self.set_forecast(row["time_to_yellow"], row["time_to_red"], row.get("p_yellow"),
                              row.get("p_red"))
        svc = self.service
        if svc is None:
            return
        st = svc.stage
        count = st.samples.count
        if count > self._samples_seen:
            self.samples.inc(count - self._samples_seen)
            self._samples_seen = count
        if st.last_sample_time is not None:
            self.model_lag.set(st.last_sample_time - st.time)
        self.events.set(len(st.associations) + len(st.pending_events))
        self.pending.set(svc.outbox.pending())
        self.dead.set(svc.outbox.dead())

    def set_forecast(self, time_to_yellow: Optional[float], time_to_red: Optional[float],
                     p_yellow: Optional[float] = None, p_red: Optional[float] = None) -> None:
        """The look-ahead's model time to yellow and red (s; None: not reached in its horizon)
        and, with an ensemble, the probabilities of reaching them (None: no ensemble)."""
        for gauge, value in ((self.time_to_yellow, time_to_yellow), (self.time_to_red, time_to_red),
                             (self.p_yellow, p_yellow), (self.p_red, p_red)):
            gauge.set(math.nan if value is None else float(value))

    # -- serving ------------------------------------------------------------------------------
    def start(self, port: int, address: str = "127.0.0.1") -> int:
        """Serve ``/metrics`` on ``address:port`` (port 0: any free one); returns the port."""
        from prometheus_client import start_http_server

        self._server, _ = start_http_server(int(port), addr=address, registry=self.registry)
        return self._server.server_address[1]

    def stop(self) -> None:
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None
