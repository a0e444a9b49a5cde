"""A durable outbox for alerts: nothing lost, nothing delivered twice under two ids.

Every alert is written to an SQLite file (stdlib ``sqlite3``, synchronous commits) before any
delivery is tried, one row per (alert id, sink); a row is marked delivered only after its
sink's ``deliver`` returned.  Undelivered rows are retried with exponential backoff
(``backoff`` * 2**attempts, capped at ``max_backoff`` seconds), also after a restart, because
they are read back from the file.  The id of an alert is computed from what it says (see
:func:`fault_screen.monitor.stage.alert_id`), so a restarted monitor that recomputes an alert
enqueues the same id again, which the outbox ignores (``INSERT OR IGNORE``): a receiver sees at
most the same id twice (at-least-once delivery; the ``webhook-id`` header lets it deduplicate),
never the same alert under two ids.

Order and independence.  Each sink has its own worker thread and its own queue (its rows): a
hung or failing receiver never delays another sink.  Within a sink alerts go in the order they
were raised, except that an alert waiting for its retry holds back only the later alerts of its
level and below: a more severe one goes past it (red overtakes yellow).  A
permanent failure (the sink raised an exception whose ``permanent`` attribute is true, e.g. a
webhook answered 4xx) moves the alert to the dead letters at once: logged as an error, counted
by :meth:`Outbox.dead`, shown by ``fault-screen plugins --outbox FILE``, and it never blocks a
later alert.
"""
from __future__ import annotations

import json
import logging
import sqlite3
import threading
import time
from pathlib import Path
from typing import Callable, Dict, Optional

__all__ = ["Outbox", "outbox_status"]

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
    level INTEGER NOT NULL DEFAULT 0,
    dead REAL,
    UNIQUE (id, sink)
)
"""
#: columns added after the first layout (an older outbox file gets them on open)
_ADDED = {"level": "INTEGER NOT NULL DEFAULT 0", "dead": "REAL"}
_PENDING = ("SELECT seq, level, next_try FROM alerts WHERE sink = ? AND delivered IS NULL "
            "AND dead IS NULL ORDER BY seq")


def _next_row(rows, now: float):
    """Among a sink's pending rows (seq, level, next_try) in the order raised: the row to try
    now (or None), and when the next one is due (or None).  A row waiting for its retry holds
    back the later rows of its level and below; a more severe one goes past it."""
    held, due = -1, None           # rows of level <= held wait behind an earlier one
    for seq, level, next_try in rows:
        if level <= held:
            continue
        if next_try <= now:
            return seq, next_try
        held = max(held, level)
        due = next_try if due is None else min(due, next_try)
    return None, due


class _Closed(Exception):
    pass


class Outbox:
    """Durable alert queue in the SQLite file ``path`` delivering to ``sinks``
    (key -> alert plugin instance; the key is the sink's identity, e.g. its ``identity``
    attribute, and must stay the same across restarts).  ``on_delivered(alert, key)`` is called
    after each delivery."""

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
        have = {r[1] for r in self._db.execute("PRAGMA table_info(alerts)")}
        for name, decl in _ADDED.items():
            if name not in have:
                self._db.execute(f"ALTER TABLE alerts ADD COLUMN {name} {decl}")
        # one deliverer per sink at a time: no row sent twice at once
        self._delivering = {key: threading.Lock() for key in self.sinks}
        self._workers: Dict[str, threading.Thread] = {}
        self._stop = False
        stale = self._db.execute(
            "SELECT DISTINCT sink FROM alerts WHERE delivered IS NULL AND dead IS NULL").fetchall()
        for (key,) in stale:
            if key not in self.sinks:
                self.log.warning("outbox %s: undelivered alerts for %s, which is not configured "
                                 "now; they wait until it is", self.path, key)
        dead = self.dead()
        if dead:
            self.log.error("outbox %s: %d alert deliveries were refused for good (dead letters); "
                           "'fault-screen plugins --outbox %s' lists them", self.path, dead,
                           self.path)

    def _sql(self, query: str, args=()):
        with self._lock:
            if self._db is None:
                raise _Closed
            return self._db.execute(query, args)

    # -- queue ------------------------------------------------------------------------------
    def put(self, alert: dict) -> int:
        """Store ``alert`` for every sink; returns how many (id, sink) rows were new."""
        payload = json.dumps(alert, sort_keys=True, default=str)
        level = alert.get("level_code")
        level = int(level) if isinstance(level, int) else 0
        now = self.clock()
        with self._lock:
            new = 0
            self._db.execute("BEGIN IMMEDIATE")
            for key in self.sinks:
                cur = self._db.execute(
                    "INSERT OR IGNORE INTO alerts (id, sink, payload, created, next_try, level) "
                    "VALUES (?, ?, ?, ?, ?, ?)", (str(alert["id"]), key, payload, now, now, level))
                new += cur.rowcount
            self._db.execute("COMMIT")
            self._wake.notify_all()
        return new

    def count(self) -> int:
        """Number of alert ids ever stored (the outbox position)."""
        return self._sql("SELECT COUNT(DISTINCT id) FROM alerts").fetchone()[0]

    def pending(self) -> int:
        """Undelivered (id, sink) rows for the configured sinks, dead letters excepted."""
        keys = list(self.sinks)
        if not keys:
            return 0
        q = ",".join("?" * len(keys))
        return self._sql(f"SELECT COUNT(*) FROM alerts WHERE delivered IS NULL AND dead IS NULL "
                         f"AND sink IN ({q})", keys).fetchone()[0]

    def dead(self) -> int:
        """(id, sink) rows refused for good (the dead letters)."""
        return self._sql("SELECT COUNT(*) FROM alerts WHERE dead IS NOT NULL").fetchone()[0]

    def rows(self):
        """All rows as dicts (for inspection and tests)."""
        cur = self._sql("SELECT seq, id, sink, level, attempts, delivered, dead, last_error "
                        "FROM alerts ORDER BY seq")
        names = [d[0] for d in cur.description]
        return [dict(zip(names, r)) for r in cur.fetchall()]

    # -- delivery ---------------------------------------------------------------------------
    def deliver_due(self, key: Optional[str] = None) -> int:
        """Try every due alert of sink ``key`` (default: of each sink in turn) once; returns
        the number delivered."""
        keys = list(self.sinks) if key is None else [key]
        done = 0
        for k in keys:
            with self._delivering[k]:
                done += self._deliver_due(k)
        return done

    def _deliver_due(self, key: str) -> int:
        sink = self.sinks[key]
        delivered = 0
        while True:
            seq, _ = _next_row(self._sql(_PENDING, (key,)).fetchall(), self.clock())
            if seq is None:
                break
            payload, attempts = self._sql("SELECT payload, attempts FROM alerts WHERE seq = ?",
                                          (seq,)).fetchone()
            alert = json.loads(payload)
            try:
                sink.deliver(alert)
            except Exception as exc:  # noqa: BLE001 - any failure is retried or dead-lettered
                error = f"{type(exc).__name__}: {exc}"
                if getattr(exc, "permanent", False):
                    self._sql("UPDATE alerts SET attempts = attempts + 1, dead = ?, "
                              "last_error = ? WHERE seq = ?", (self.clock(), error, seq))
                    self.log.error("alert %s (%s) to %s refused for good, moved to the dead "
                                   "letters of %s: %s", alert["id"], alert.get("level"), key,
                                   self.path, exc)
                    continue
                wait = min(self.backoff * 2 ** attempts, self.max_backoff)
                self._sql("UPDATE alerts SET attempts = attempts + 1, next_try = ?, "
                          "last_error = ? WHERE seq = ?", (self.clock() + wait, error, seq))
                self.log.warning("alert %s to %s not delivered (attempt %d): %s; retry in "
                                 "%.3g s", alert["id"], key, attempts + 1, exc, wait)
                break
            self._sql("UPDATE alerts SET attempts = attempts + 1, delivered = ?, "
                      "last_error = NULL WHERE seq = ?", (self.clock(), seq))
            delivered += 1
            if self.on_delivered is not None:
                self.on_delivered(alert, key)
        return delivered

    def next_due(self, key: Optional[str] = None) -> Optional[float]:
        """When the next delivery attempt of sink ``key`` (default: of any sink) is due (clock
        time), or None if nothing is pending."""
        times = []
        for k in (list(self.sinks) if key is None else [key]):
            seq, due = _next_row(self._sql(_PENDING, (k,)).fetchall(), self.clock())
            when = self.clock() if seq is not None else due
            if when is not None:
                times.append(when)
        return min(times) if times else None

    def start(self) -> None:
        """Deliver in background threads, one per sink (alerts go out while the model steps)."""
        with self._lock:
            self._stop = False
            for key in self.sinks:
                if key not in self._workers:
                    t = threading.Thread(target=self._run, args=(key,), daemon=True,
                                         name=f"outbox {key}")
                    self._workers[key] = t
                    t.start()

    def _run(self, key: str) -> None:
        try:
            while True:
                with self._lock:
                    if self._stop:
                        return
                self.deliver_due(key)
                with self._lock:
                    if self._stop:
                        return
                    due = self.next_due(key)
                    wait = 1.0 if due is None else min(1.0, max(0.0, due - self.clock()))
                    if wait > 0:
                        self._wake.wait(wait)
        except _Closed:
            return

    def drain(self, timeout: float) -> int:
        """Keep delivering (the workers) until nothing is pending or ``timeout`` seconds passed;
        returns the number still pending (they stay in the file for the next start)."""
        self.start()
        end = time.monotonic() + timeout
        while self.pending() and time.monotonic() < end:
            with self._lock:
                self._wake.notify_all()
                self._wake.wait(min(0.05, max(0.0, end - time.monotonic())))
        return self.pending()

    def close(self) -> None:
        """Stop the workers and close the file.  A worker inside a sink that does not return
        (a hung receiver) is left behind: its row stays undelivered in the file."""
        with self._lock:
            self._stop = True
            self._wake.notify_all()
        for t in self._workers.values():
            t.join(timeout=1.0)
        self._workers = {}
        with self._lock:
            if self._db is not None:
                self._db.close()
                self._db = None


def outbox_status(path) -> dict:
    """What an outbox file holds, per sink: ``pending``, ``delivered``, ``dead`` counts, and the
    dead letters (id, level, sink, error)."""
    if not Path(path).is_file():
        raise ValueError(f"{path}: no such outbox file")
    db = sqlite3.connect(str(path))
    try:
        cols = {r[1] for r in db.execute("PRAGMA table_info(alerts)")}
        if not cols:
            raise ValueError(f"{path}: not an alert outbox (no alerts table)")
        dead_col = "dead" if "dead" in cols else "NULL"
        sinks = {}
        for sink, delivered, dead in db.execute(
                f"SELECT sink, delivered, {dead_col} FROM alerts"):
            s = sinks.setdefault(sink, {"pending": 0, "delivered": 0, "dead": 0})
            s["dead" if dead is not None else "delivered" if delivered is not None else "pending"] += 1
        letters = [] if dead_col == "NULL" else [
            dict(zip(("id", "level", "sink", "error"), r)) for r in db.execute(
                "SELECT id, level, sink, last_error FROM alerts WHERE dead IS NOT NULL ORDER BY seq")]
        return {"sinks": sinks, "dead_letters": letters}
    except sqlite3.DatabaseError as exc:
        raise ValueError(f"{path}: not an alert outbox ({exc})") from None
    finally:
        db.close()
