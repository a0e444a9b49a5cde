"""Screening metrics of one output time (or of every output time at once) from the result arrays.

Definitions (``mu0 = scene.fault.friction``; stresses from ``/fault``, compression positive):

* ``peak_slip_rate`` (m/s): max over the fault of |slip rate|; ``x_peak_slip_rate`` (m) where
  it peaks (along the fault from the injection point; NaN while the whole fault is at rest);
* ``slipping_length`` (m): sum of the quadrature weights of the points in sliding contact
  (contact_state 1);
* ``max_utilisation`` (-): max of |tau| / (mu0 sigma'_n); an open point (contact_state 2, or no
  compression left) counts as 1, i.e. at failure.  mu0 is the strength coefficient for Coulomb
  and rate-and-state alike: the regularised rate-and-state friction of a point at rest drops
  towards 0 with its slip rate and would read as failure;
* ``min_coulomb_margin`` (Pa): min of mu0 max(sigma'_n, 0) - |tau| (0 at failure and where open);
* ``delta_cff`` (Pa): change since t = 0 of the Coulomb failure function |tau| - mu0 sigma'_n at
  the injection point (positive: towards failure);
* ``injection_overpressure`` (Pa): ``/injection/overpressure``;
* ``induced_slip`` (m): |sum of the increments of ``/injection/slip`` over the output intervals
  at whose end the injection point is in sliding contact|.  Why: the contact is a penalty
  spring, so a locked point still moves elastically by (tau - tau0)/kT as the load changes, and
  the regularised rate-and-state law lets a loaded fault at rest creep below the slipping
  threshold (about 3e-10 m in 300 s for the calibrated Rustrel scene at zero rate).  Neither is
  slip induced by injection.  Gating by the contact state counts neither, so a fault that never
  slides gives exactly 0; slip gained while sliding is kept after the point locks again.  The
  state is that of the fault quadrature point nearest to the injection point (as
  ``/injection/slip_rate``).
"""
from __future__ import annotations

import numpy as np

SLIP, OPEN = 1, 2

#: the fault-point metrics, in the order they are stored
FAULT_METRICS = ("peak_slip_rate", "x_peak_slip_rate", "slipping_length", "max_utilisation",
                 "min_coulomb_margin")
#: the injection-point metrics
POINT_METRICS = ("delta_cff", "injection_overpressure", "induced_slip")
#: fault arrays the metrics read
FAULT_FIELDS = ("slip_rate", "contact_state", "shear_traction", "effective_normal_stress")
#: injection-point series the metrics read
INJECTION_FIELDS = ("overpressure", "slip", "shear_traction", "effective_normal_stress")


def injection_point_index(fault_x) -> int:
    """Index of the fault quadrature point nearest to the injection point (x = 0)."""
    x = np.asarray(fault_x, dtype=float)
    return int(np.argmin(np.abs(x))) if x.size else 0


def fault_metrics(fault: dict, fault_x, fault_weights, mu0: float) -> dict:
    """The fault-point metrics of one row (arrays shaped (x,)) or of every row ((time, x)):
    returns floats or (time,) arrays, keyed as :data:`FAULT_METRICS`."""
    x = np.asarray(fault_x, dtype=float)
    w = np.asarray(fault_weights, dtype=float)
    rate = np.abs(np.asarray(fault["slip_rate"], dtype=float))
    state = np.asarray(fault["contact_state"])
    tau = np.abs(np.asarray(fault["shear_traction"], dtype=float))
    sn = np.asarray(fault["effective_normal_stress"], dtype=float)
    if x.size == 0:  # a scene without a fault
        shape = rate.shape[:-1]
        nan = np.full(shape, np.nan)
        out = dict(peak_slip_rate=np.zeros(shape), x_peak_slip_rate=nan, slipping_length=np.zeros(shape),
                   max_utilisation=np.zeros(shape), min_coulomb_margin=nan)
        return {k: (float(v) if np.ndim(v) == 0 else v) for k, v in out.items()}
    if rate.ndim == 1:
        return _row_fault_metrics(x, w, rate, state, tau, sn, mu0)
    peak = rate.max(axis=-1)
    where = np.take(x, rate.argmax(axis=-1))
    x_peak = np.where(peak > 0, where, np.nan)
    sliding_length = np.sum(w * (state == SLIP), axis=-1)
    strength = mu0 * np.maximum(sn, 0.0)
    at_failure = (state == OPEN) | (strength <= 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        util = np.where(at_failure, 1.0, tau / np.where(at_failure, 1.0, strength))
    out = dict(peak_slip_rate=peak, x_peak_slip_rate=x_peak, slipping_length=sliding_length,
               max_utilisation=util.max(axis=-1), min_coulomb_margin=(strength - tau).min(axis=-1))
    return {k: (float(v) if np.ndim(v) == 0 else v) for k, v in out.items()}


def _row_fault_metrics(x, w, rate, state, tau, sn, mu0) -> dict:
    """``fault_metrics`` of one row in half the numpy calls (the live monitor and a screened
    run call it every step): the same operations on each number, so the same floats."""
    strength = mu0 * np.maximum(sn, 0.0)
    at_failure = (state == OPEN) | (strength <= 0)
    utilisation = np.divide(tau, strength, out=np.ones_like(tau), where=~at_failure)
    g = int(rate.argmax())   # (the first NaN, if any: then the peak is NaN, as max makes it)
    peak = float(rate[g])
    return dict(peak_slip_rate=peak, x_peak_slip_rate=float(x[g]) if peak > 0 else np.nan,
                slipping_length=float(np.sum(w * (state == SLIP))),
                max_utilisation=float(utilisation.max()),
                min_coulomb_margin=float((strength - tau).min()))


def coulomb_failure_function(tau, sigma_n, mu0):
    """|tau| - mu0 sigma'_n (Pa): negative below failure."""
    return np.abs(tau) - mu0 * np.asarray(sigma_n, dtype=float)


class MetricsTracker:
    """Metrics of successive output rows, one call per row (what the live monitor does per step)
    or per block of rows (:meth:`block`: a result file read in pieces).

    Keeps what the point metrics need from earlier rows: the Coulomb failure function at the first
    row (reference of ``delta_cff``), the previous injection-point slip and the induced slip so far.
    """

    def __init__(self, fault_x, fault_weights, mu0: float):
        self.fault_x = np.asarray(fault_x, dtype=float)
        self.fault_weights = np.asarray(fault_weights, dtype=float)
        self.mu0 = float(mu0)
        self.point = injection_point_index(self.fault_x)
        self._cff0 = None
        self._slip_before = None
        self.induced_slip_signed = 0.0

    def state(self) -> dict:
        """What the tracker keeps of earlier rows, as plain data (the geometry is the model's)."""
        return {"cff0": self._cff0, "slip_before": self._slip_before,
                "induced_slip_signed": self.induced_slip_signed}

    @classmethod
    def from_state(cls, fault_x, fault_weights, mu0: float, state: dict) -> "MetricsTracker":
        out = cls(fault_x, fault_weights, mu0)
        out._cff0 = None if state["cff0"] is None else float(state["cff0"])
        out._slip_before = None if state["slip_before"] is None else float(state["slip_before"])
        out.induced_slip_signed = float(state["induced_slip_signed"])
        return out

    def row_metrics(self, row: dict) -> dict:
        """Metrics of a row the stepper recorded (``Simulation.last_row``: fault arrays and the
        ``inj_*`` values at the injection point)."""
        at = lambda k: float(np.asarray(row[k], dtype=float).reshape(-1)[self.point]) \
            if np.size(row[k]) else 0.0  # noqa: E731
        return self.update({k: row[k] for k in FAULT_FIELDS},
                           {"overpressure": row["inj_overpressure"], "slip": row["inj_slip"],
                            "shear_traction": at("shear_traction"),
                            "effective_normal_stress": at("effective_normal_stress")})

    @classmethod
    def for_result(cls, result) -> "MetricsTracker":
        return cls(result.fault_x, result.fault_weights, result.scene.fault.friction)

    def update(self, fault_row: dict, injection_row: dict) -> dict:
        """Metrics of one row: ``fault_row`` maps :data:`FAULT_FIELDS` to (x,) arrays,
        ``injection_row`` maps :data:`INJECTION_FIELDS` to floats (SI)."""
        out = fault_metrics(fault_row, self.fault_x, self.fault_weights, self.mu0)
        cff = float(coulomb_failure_function(injection_row["shear_traction"],
                                             injection_row["effective_normal_stress"], self.mu0))
        if self._cff0 is None:
            self._cff0 = cff
        slip = float(injection_row["slip"])
        state = np.asarray(fault_row["contact_state"])
        sliding = state.size > 0 and int(state[self.point]) == SLIP
        if self._slip_before is not None and sliding:
            self.induced_slip_signed += slip - self._slip_before
        self._slip_before = slip
        out["delta_cff"] = cff - self._cff0
        out["injection_overpressure"] = float(injection_row["overpressure"])
        out["induced_slip"] = abs(self.induced_slip_signed)
        return out

    def row(self, result, i: int) -> dict:
        """Metrics of row ``i`` of a :class:`~fault_screen.Result` (rows must come in order)."""
        return self.update({k: result.fault[k][i] for k in FAULT_FIELDS},
                           {k: result.injection[k][i] for k in INJECTION_FIELDS})


    def block(self, fault: dict, injection: dict) -> dict:
        """Metrics of the next block of rows (the first block starting at row 0), (rows,) arrays:
        the same numbers as :func:`result_metrics` over the whole result, whatever the blocks.
        ``fault``: :data:`FAULT_FIELDS` -> (rows, x) arrays; ``injection``:
        :data:`INJECTION_FIELDS` -> (rows,) arrays (SI)."""
        mu0 = self.mu0
        out = fault_metrics({k: fault[k] for k in FAULT_FIELDS}, self.fault_x, self.fault_weights, mu0)
        n = len(injection["overpressure"])
        out = {k: np.broadcast_to(np.asarray(v, dtype=float), (n,)).copy() for k, v in out.items()}
        if not n:
            out.update({k: np.zeros(0) for k in POINT_METRICS})
            return out
        cff = coulomb_failure_function(np.asarray(injection["shear_traction"], dtype=float),
                                       injection["effective_normal_stress"], mu0)
        if self._cff0 is None:
            self._cff0 = float(cff[0])
        out["delta_cff"] = cff - self._cff0
        out["injection_overpressure"] = np.asarray(injection["overpressure"], dtype=float).copy()
        slip = np.asarray(injection["slip"], dtype=float)
        state = np.asarray(fault["contact_state"])
        if state.shape[-1]:
            sliding = state[:, self.point] == SLIP
            # the increment into each row; the first row of the run has none
            before = slip[:1] if self._slip_before is None else np.array([self._slip_before])
            steps = np.where(sliding, np.diff(np.concatenate([before, slip])), 0.0)
            if self._slip_before is None:
                steps[0] = 0.0
            # one running sum over the whole run, in row order (cumsum adds in sequence)
            total = np.cumsum(np.concatenate([[self.induced_slip_signed], steps]))[1:]
            self.induced_slip_signed = float(total[-1])
            out["induced_slip"] = np.abs(total)
        else:
            out["induced_slip"] = np.zeros(n)
        self._slip_before = float(slip[-1])
        return out


def result_metrics(result) -> dict:
    """Every metric of every output row of ``result`` at once: (time,) arrays; the same numbers
    as :class:`MetricsTracker` row by row."""
    return MetricsTracker.for_result(result).block(result.fault, result.injection)
