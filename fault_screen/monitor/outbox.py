"""A durable outbox for alerts: nothing lost, nothing delivered twice under two ids.

Every alert is written to an SQLite file (stdlib ``sqlite3``, synchronous commits) before any
delivery is tried, one row per (alert id, sink); a row is marked delivered only after its
sink's ``deliver`` returned.  Undelivered rows are retried with exponential backoff
(``backoff`` * 2**attempts, capped at ``max_backoff`` seconds), also after a restart, because
they are read back from the file.  The id of an alert is computed from what it says (see
:func:`fault_screen.monitor.stage.alert_id`), so a restarted monitor that recomputes an alert
enqueues the same id again, which the outbox ignores (``INSERT OR IGNORE``): a receiver sees at
most the same id twice (at-least-once delivery; the ``webhook-id`` header lets it deduplicate),
never the same alert under two ids.  Alerts reach one sink in the order they were raised: a
failing alert holds back the later ones of that sink.
"""
from __future__ import annotations

import json
import logging
import sqlite3
import threading
import time
from pathlib import Path
from typing import Callable, Dict, Optional

__all__ = ["Outbox"]

_SCHEMA = """
CREATE TABLE IF NOT EXISTS alerts (
    seq INTEGER PRIMARY KEY AUTOINCREMENT,
    id TEXT NOT NULL,
    sink TEXT NOT NULL,
    payload TEXT NOT NULL,
    created REAL NOT NULL,
    attempts INTEGER NOT NULL DEFAULT 0,
    next_try REAL NOT NULL,
    delivered REAL,
    last_error TEXT,
    UNIQUE (id, sink)
)
"""


class Outbox:
    """Durable alert queue in the SQLite file ``path`` delivering to ``sinks``
    (key -> alert plugin instance; the key, e.g. the ``--alert`` spec, must stay the same across
    restarts).  ``on_delivered(alert, key)`` is called after each delivery."""

    def __init__(self, path, sinks: Dict[str, object], *, backoff: float = 1.0,
                 max_backoff: float = 300.0, log: Optional[logging.Logger] = None,
                 on_delivered: Optional[Callable[[dict, str], None]] = None,
                 clock: Callable[[], float] = time.time):
        self.path = Path(path)
        self.sinks = dict(sinks)
        self.backoff, self.max_backoff = float(backoff), float(max_backoff)
        self.log = log or logging.getLogger("fault_screen.monitor.outbox")
        self.on_delivered = on_delivered
        self.clock = clock
        self._lock = threading.RLock()
        self._wake = threading.Condition(self._lock)
        self._db = sqlite3.connect(str(self.path), check_same_thread=False, isolation_level=None)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=FULL")
        self._db.execute(_SCHEMA)
        self._delivering = threading.Lock()   # one deliverer at a time: no row sent twice at once
        self._thread: Optional[threading.Thread] = None
        self._stop = False
        stale = self._db.execute(
            "SELECT DISTINCT sink FROM alerts WHERE delivered IS NULL").fetchall()
        for (key,) in stale:
            if key not in self.sinks:
                self.log.warning("outbox %s: undelivered alerts for %r, which is not configured "
                                 "now; they wait until it is", self.path, key)

    # -- queue ------------------------------------------------------------------------------
    def put(self, alert: dict) -> int:
        """Store ``alert`` for every sink; returns how many (id, sink) rows were new."""
        payload = json.dumps(alert, sort_keys=True, default=str)
        now = self.clock()
        with self._lock:
            new = 0
            self._db.execute("BEGIN IMMEDIATE")
            for key in self.sinks:
                cur = self._db.execute(
                    "INSERT OR IGNORE INTO alerts (id, sink, payload, created, next_try) "
                    "VALUES (?, ?, ?, ?, ?)", (str(alert["id"]), key, payload, now, now))
                new += cur.rowcount
            self._db.execute("COMMIT")
            self._wake.notify_all()
        return new

    def count(self) -> int:
        """Number of alert ids ever stored (the outbox position)."""
        with self._lock:
            return self._db.execute("SELECT COUNT(DISTINCT id) FROM alerts").fetchone()[0]

    def pending(self) -> int:
        """Undelivered (id, sink) rows for the configured sinks."""
        with self._lock:
            keys = list(self.sinks)
            if not keys:
                return 0
            q = ",".join("?" * len(keys))
            return self._db.execute(f"SELECT COUNT(*) FROM alerts WHERE delivered IS NULL AND "
                                    f"sink IN ({q})", keys).fetchone()[0]

    def rows(self):
        """All rows as dicts (for inspection and tests)."""
        with self._lock:
            cur = self._db.execute("SELECT seq, id, sink, attempts, delivered, last_error "
                                   "FROM alerts ORDER BY seq")
            names = [d[0] for d in cur.description]
            return [dict(zip(names, r)) for r in cur.fetchall()]

    # -- delivery ---------------------------------------------------------------------------
    def deliver_due(self) -> int:
        """Try every due alert once (in order per sink); returns the number delivered."""
        with self._delivering:
            return self._deliver_due()

    def _deliver_due(self) -> int:
        delivered = 0
        for key, sink in self.sinks.items():
            while True:
                with self._lock:
                    row = self._db.execute(
                        "SELECT seq, payload, attempts, next_try FROM alerts WHERE sink = ? AND "
                        "delivered IS NULL ORDER BY seq LIMIT 1", (key,)).fetchone()
                if row is None or row[3] > self.clock():
                    break
                seq, payload, attempts, _ = row
                alert = json.loads(payload)
                try:
                    sink.deliver(alert)
                except Exception as exc:  # noqa: BLE001 - any failure is retried later
                    wait = min(self.backoff * 2 ** attempts, self.max_backoff)
                    with self._lock:
                        self._db.execute(
                            "UPDATE alerts SET attempts = attempts + 1, next_try = ?, "
                            "last_error = ? WHERE seq = ?",
                            (self.clock() + wait, f"{type(exc).__name__}: {exc}", seq))
                    self.log.warning("alert %s to %s not delivered (attempt %d): %s; retry in "
                                     "%.3g s", alert["id"], key, attempts + 1, exc, wait)
                    break
                with self._lock:
                    self._db.execute("UPDATE alerts SET attempts = attempts + 1, delivered = ?, "
                                     "last_error = NULL WHERE seq = ?", (self.clock(), seq))
                delivered += 1
                if self.on_delivered is not None:
                    self.on_delivered(alert, key)
        return delivered

    def next_due(self) -> Optional[float]:
        """When the next delivery attempt is due (clock time), or None if nothing is pending:
        the earliest retry time among the first undelivered alerts of each sink."""
        times = []
        with self._lock:
            for key in self.sinks:
                r = self._db.execute("SELECT next_try FROM alerts WHERE sink = ? AND delivered "
                                     "IS NULL ORDER BY seq LIMIT 1", (key,)).fetchone()
                if r is not None:
                    times.append(r[0])
        return min(times) if times else None

    def start(self) -> None:
        """Deliver in a background thread (alerts go out while the model steps)."""
        if self._thread is None:
            self._stop = False
            self._thread = threading.Thread(target=self._run, name="outbox", daemon=True)
            self._thread.start()

    def _run(self) -> None:
        while True:
            with self._lock:
                if self._stop:
                    return
            self.deliver_due()
            with self._lock:
                if self._stop:
                    return
                due = self.next_due()
                wait = 1.0 if due is None else min(1.0, max(0.0, due - self.clock()))
                if wait > 0:
                    self._wake.wait(wait)

    def drain(self, timeout: float) -> int:
        """Keep delivering until nothing is pending or ``timeout`` seconds passed; returns the
        number still pending (they stay in the file for the next start)."""
        end = time.monotonic() + timeout
        while self.pending() and time.monotonic() < end:
            self.deliver_due()
            due = self.next_due()
            if due is None:
                break
            time.sleep(max(0.0, min(due - self.clock(), end - time.monotonic(), 0.2)))
        return self.pending()

    def close(self) -> None:
        with self._lock:
            self._stop = True
            self._wake.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=30)
            self._thread = None
        with self._lock:
            self._db.close()
