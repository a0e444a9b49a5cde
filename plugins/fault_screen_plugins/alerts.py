"""Built-in alert plugins: ``jsonl``, ``webhook``, ``command``.

Each takes its options as keyword arguments and delivers one alert dict with ``deliver``;
an exception means "not delivered" (the monitor's outbox retries later with the same id).
"""
from __future__ import annotations

import base64
import hashlib
import hmac
import json
import logging
import os
import subprocess
import time
import urllib.error
import urllib.request
from pathlib import Path

__all__ = ["JsonlAlert", "WebhookAlert", "CommandAlert", "sign"]

log = logging.getLogger("fault_screen.alerts")


def _body(alert: dict) -> bytes:
    # one canonical serialisation: the bytes signed are the bytes sent
    return json.dumps(alert, sort_keys=True, separators=(",", ":"), allow_nan=False,
                      default=str).encode("utf-8")


class JsonlAlert:
    """Append each alert as one JSON line to ``path`` (flushed and fsync'ed)."""

    main_option = "path"

    def __init__(self, path: str):
        self.path = Path(path)
        if self.path.parent and not self.path.parent.is_dir():
            raise ValueError(f"path {path!r}: folder {str(self.path.parent)!r} does not exist")

    def deliver(self, alert: dict) -> None:
        with open(self.path, "ab") as fh:
            fh.write(_body(alert) + b"\n")
            fh.flush()
            os.fsync(fh.fileno())


def secret_key(secret: str) -> bytes:
    """The HMAC key of a Standard Webhooks secret: base64, optionally prefixed ``whsec_``."""
    s = secret.strip()
    if s.startswith("whsec_"):
        s = s[len("whsec_"):]
    try:
        key = base64.b64decode(s, validate=True)
    except ValueError:
        raise ValueError("the webhook secret is not base64 (optionally prefixed 'whsec_')") from None
    if not key:
        raise ValueError("the webhook secret is empty")
    return key


def sign(key: bytes, msg_id: str, timestamp: int, body: bytes) -> str:
    """``v1,`` + base64 HMAC-SHA256 of ``{id}.{timestamp}.{body}`` (Standard Webhooks)."""
    signed = msg_id.encode() + b"." + str(int(timestamp)).encode() + b"." + body
    return "v1," + base64.b64encode(hmac.new(key, signed, hashlib.sha256).digest()).decode()


class WebhookAlert:
    """POST the alert as JSON to ``url``, signed as the Standard Webhooks convention does.

    Headers ``webhook-id`` (the alert's idempotency key, the same on every attempt),
    ``webhook-timestamp`` (Unix seconds of the attempt) and ``webhook-signature``; the secret
    is read from the environment variable ``secret_env`` (base64, optionally ``whsec_``-prefixed;
    without ``secret_env`` the request is sent unsigned).  A connection error, a timeout or an
    HTTP 408/409/425/429/5xx answer is retried ``retries`` times after ``backoff``, 2 ``backoff``,
    4 ``backoff``... seconds (capped at ``max_backoff``); other 4xx answers fail at once.
    """

    main_option = "url"
    RETRY_STATUS = {408, 409, 425, 429}

    def __init__(self, url: str, secret_env: str | None = None, retries: int = 4,
                 backoff: float = 0.5, max_backoff: float = 30.0, timeout: float = 10.0):
        if not str(url).startswith(("http://", "https://")):
            raise ValueError(f"url {url!r}: must start with http:// or https://")
        self.url = str(url)
        self.key = None
        if secret_env is not None:
            value = os.environ.get(str(secret_env))
            if value is None:
                raise ValueError(f"secret_env: environment variable {secret_env!r} is not set")
            try:
                self.key = secret_key(value)
            except ValueError as exc:
                raise ValueError(f"secret_env {secret_env!r}: {exc}") from None
        self.retries, self.backoff = int(retries), float(backoff)
        self.max_backoff, self.timeout = float(max_backoff), float(timeout)
        if self.retries < 0 or self.backoff < 0 or self.timeout <= 0:
            raise ValueError("retries and backoff must be >= 0 and timeout > 0")

    def _attempt(self, alert_id: str, body: bytes) -> None:
        ts = int(time.time())
        headers = {"content-type": "application/json", "webhook-id": alert_id,
                   "webhook-timestamp": str(ts), "user-agent": "fault-screen"}
        if self.key is not None:
            headers["webhook-signature"] = sign(self.key, alert_id, ts, body)
        req = urllib.request.Request(self.url, data=body, headers=headers, method="POST")
        with urllib.request.urlopen(req, timeout=self.timeout) as resp:
            resp.read()

    def deliver(self, alert: dict) -> None:
        body = _body(alert)
        alert_id = str(alert["id"])
        for attempt in range(self.retries + 1):
            try:
                self._attempt(alert_id, body)
                return
            except urllib.error.HTTPError as exc:
                retry = exc.code in self.RETRY_STATUS or exc.code >= 500
                why = f"HTTP {exc.code}"
                if not retry:
                    raise RuntimeError(f"webhook {self.url}: {why}, not retried") from None
            except (urllib.error.URLError, OSError) as exc:
                why = f"{type(exc).__name__}: {getattr(exc, 'reason', exc)}"
            if attempt == self.retries:
                raise RuntimeError(f"webhook {self.url}: {why} after {attempt + 1} attempts")
            wait = min(self.backoff * 2 ** attempt, self.max_backoff)
            log.warning("webhook %s: %s; retry %d/%d in %.3g s", self.url, why, attempt + 1,
                        self.retries, wait)
            time.sleep(wait)


class CommandAlert:
    """Run a program for each alert: ``argv`` is an argument list (never a shell string).

    The alert JSON is written to the program's standard input and also given in the
    environment as ``FAULT_SCREEN_ALERT`` (with ``FAULT_SCREEN_ALERT_ID`` and
    ``FAULT_SCREEN_LEVEL``).  A non-zero exit status or a run longer than ``timeout`` seconds
    is a failed delivery.
    """

    main_option = "argv"

    def __init__(self, argv, timeout: float = 30.0):
        if isinstance(argv, str):
            raise ValueError('argv must be an argument list, not a shell string; e.g. '
                             'command:["/usr/bin/logger", "-t", "fault-screen"]')
        if not argv or not all(isinstance(a, str) for a in argv):
            raise ValueError("argv must be a non-empty list of strings")
        self.argv, self.timeout = list(argv), float(timeout)

    def deliver(self, alert: dict) -> None:
        body = _body(alert)
        env = dict(os.environ, FAULT_SCREEN_ALERT=body.decode(),
                   FAULT_SCREEN_ALERT_ID=str(alert["id"]), FAULT_SCREEN_LEVEL=str(alert["level"]))
        proc = subprocess.run(self.argv, input=body, env=env, capture_output=True,
                              timeout=self.timeout, shell=False)
        if proc.returncode != 0:
            err = proc.stderr.decode(errors="replace").strip().splitlines()
            raise RuntimeError(f"command {self.argv[0]} exited with status {proc.returncode}"
                               + (f": {err[-1]}" if err else ""))
