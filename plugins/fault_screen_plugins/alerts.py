"""Built-in alert plugins: ``jsonl``, ``webhook``, ``command``.

Each takes its options as keyword arguments and delivers one alert dict with ``deliver``;
an exception means "not delivered" (the monitor's outbox retries later with the same id), and an
exception whose ``permanent`` attribute is true (:class:`DeliveryRefused`) means "never
deliverable" (the outbox moves the alert to its dead letters, reported, and goes on).  Each has
an ``identity``: what it delivers to, without secrets (the outbox keys its rows by it).
"""
from __future__ import annotations

import base64
import hashlib
import hmac
import json
import logging
import os
import subprocess
import tempfile
import time
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

__all__ = ["JsonlAlert", "WebhookAlert", "CommandAlert", "DeliveryRefused", "sign", "redact_url"]

log = logging.getLogger("fault_screen.alerts")

#: environment variables holding webhook secrets in this process: never passed to a command
_SECRET_VARIABLES: set[str] = set()


class DeliveryRefused(RuntimeError):
    """The receiver refused the alert for good (retrying cannot help): the outbox moves it to
    its dead letters instead of retrying it."""

    permanent = True


def redact_url(url: str) -> str:
    """``url`` without what may be a credential: user and password, path and query (webhook
    services put their tokens there) become ``***``; scheme, host and port stay."""
    try:
        parts = urllib.parse.urlsplit(str(url))
        host = parts.hostname or ""
        port = parts.port
    except ValueError:
        return "<unparsable url>"
    if ":" in host:
        host = f"[{host}]"
    out = f"{parts.scheme}://" + ("***@" if parts.username or parts.password else "") + host
    out += f":{port}" if port is not None else ""
    out += "/***" if parts.path.strip("/") else parts.path
    return out + ("?***" if parts.query else "")


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

    @property
    def identity(self) -> str:
        return f"jsonl:{self.path.resolve()}"

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


class _NoRedirect(urllib.request.HTTPRedirectHandler):
    """Redirects are answered as errors: a POST re-sent as a GET loses its body, and the
    signature headers must not follow to another host."""

    def redirect_request(self, req, fp, code, msg, headers, newurl):
        return None


_OPENER = urllib.request.build_opener(_NoRedirect)


class WebhookAlert:
    """POST the alert as JSON to ``url``, signed as the Standard Webhooks convention does.

    Headers ``webhook-id`` (the alert's idempotency key, the same on every attempt),
    ``webhook-timestamp`` (Unix seconds of the attempt) and ``webhook-signature``; the secret
    is read from the environment variable ``secret_env`` (base64, optionally ``whsec_``-prefixed;
    without ``secret_env`` the request is sent unsigned).  A connection error, a timeout or an
    HTTP 408/409/425/429/5xx answer is retried ``retries`` times after ``backoff``, 2 ``backoff``,
    4 ``backoff``... seconds (capped at ``max_backoff``); other 4xx answers are refused for good
    (dead letter).  A redirect (3xx) is never followed: the delivery fails and is retried later
    (fix the URL).  The URL is shown and stored with its path, query and password hidden.
    """

    main_option = "url"
    RETRY_STATUS = {408, 409, 425, 429}

    def __init__(self, url: str, secret_env: str | None = None, retries: int = 4,
                 backoff: float = 0.5, max_backoff: float = 30.0, timeout: float = 10.0):
        if not str(url).startswith(("http://", "https://")):
            raise ValueError(f"url {redact_url(url)!r}: must start with http:// or https://")
        self.url = str(url)
        self.shown = redact_url(self.url)
        self.key = None
        if secret_env is not None:
            value = os.environ.get(str(secret_env))
            if value is None:
                raise ValueError(f"secret_env: environment variable {secret_env!r} is not set")
            try:
                self.key = secret_key(value)
            except ValueError as exc:
                raise ValueError(f"secret_env {secret_env!r}: {exc}") from None
            _SECRET_VARIABLES.add(str(secret_env))
        self.retries, self.backoff = int(retries), float(backoff)
        self.max_backoff, self.timeout = float(max_backoff), float(timeout)
        if self.retries < 0 or self.backoff < 0 or self.timeout <= 0:
            raise ValueError("retries and backoff must be >= 0 and timeout > 0")

    @property
    def identity(self) -> str:
        # the URL's digest tells two hooks on one host apart without storing its token
        digest = hashlib.sha256(self.url.encode()).hexdigest()[:12]
        return f"webhook:{self.shown}#{digest}"

    def __repr__(self):
        return f"WebhookAlert({self.shown!r})"

    def _attempt(self, alert_id: str, body: bytes) -> None:
        ts = int(time.time())
        headers = {"content-type": "application/json", "webhook-id": alert_id,
                   "webhook-timestamp": str(ts), "user-agent": "fault-screen"}
        if self.key is not None:
            headers["webhook-signature"] = sign(self.key, alert_id, ts, body)
        req = urllib.request.Request(self.url, data=body, headers=headers, method="POST")
        with _OPENER.open(req, timeout=self.timeout) as resp:
            resp.read()

    def deliver(self, alert: dict) -> None:
        body = _body(alert)
        alert_id = str(alert["id"])
        for attempt in range(self.retries + 1):
            try:
                self._attempt(alert_id, body)
                return
            except urllib.error.HTTPError as exc:
                if 300 <= exc.code < 400:
                    where = exc.headers.get("location") if exc.headers else None
                    to = f" to {redact_url(urllib.parse.urljoin(self.url, where))}" if where else ""
                    log.error("webhook %s: HTTP %d redirect%s not followed: give the final URL",
                              self.shown, exc.code, to)
                    raise RuntimeError(f"webhook {self.shown}: HTTP {exc.code} redirect{to} not "
                                       f"followed (a webhook POST is never redirected: give the "
                                       f"final URL)") from None
                retry = exc.code in self.RETRY_STATUS or exc.code >= 500
                why = f"HTTP {exc.code}"
                if not retry:
                    raise DeliveryRefused(f"webhook {self.shown}: {why}, not retried") from None
            except (urllib.error.URLError, OSError) as exc:
                why = f"{type(exc).__name__}: {getattr(exc, 'reason', exc)}"
            if attempt == self.retries:
                raise RuntimeError(f"webhook {self.shown}: {why} after {attempt + 1} attempts")
            wait = min(self.backoff * 2 ** attempt, self.max_backoff)
            log.warning("webhook %s: %s; retry %d/%d in %.3g s", self.shown, why, attempt + 1,
                        self.retries, wait)
            time.sleep(wait)


class CommandAlert:
    """Run a program for each alert: ``argv`` is an argument list (never a shell string).

    The alert JSON is written to the program's standard input and also given in the
    environment as ``FAULT_SCREEN_ALERT`` (with ``FAULT_SCREEN_ALERT_ID`` and
    ``FAULT_SCREEN_LEVEL``); the variables holding webhook secrets are not passed on.  The
    delivery is the exit status of the program itself: 0 is delivered, even when it leaves a
    background process running; a non-zero status, or no exit within ``timeout`` seconds (the
    program is then killed), is a failed delivery.
    """

    main_option = "argv"

    def __init__(self, argv, timeout: float = 30.0):
        if isinstance(argv, str):
            raise ValueError('argv must be an argument list, not a shell string; e.g. '
                             'command:["/usr/bin/logger", "-t", "fault-screen"]')
        if not argv or not all(isinstance(a, str) for a in argv):
            raise ValueError("argv must be a non-empty list of strings")
        self.argv, self.timeout = list(argv), float(timeout)

    @property
    def identity(self) -> str:
        return "command:" + json.dumps(self.argv)

    def deliver(self, alert: dict) -> None:
        body = _body(alert)
        env = {k: v for k, v in os.environ.items() if k not in _SECRET_VARIABLES}
        env.update(FAULT_SCREEN_ALERT=body.decode(), FAULT_SCREEN_ALERT_ID=str(alert["id"]),
                   FAULT_SCREEN_LEVEL=str(alert["level"]))
        # files, not pipes: a background child keeping them open cannot hold the delivery
        with tempfile.TemporaryFile() as stdin, tempfile.TemporaryFile() as stderr:
            stdin.write(body)
            stdin.seek(0)
            proc = subprocess.Popen(self.argv, stdin=stdin, stdout=subprocess.DEVNULL,
                                    stderr=stderr, env=env, shell=False)
            try:
                status = proc.wait(timeout=self.timeout)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
                raise RuntimeError(f"command {self.argv[0]} did not exit within "
                                   f"{self.timeout:g} s (killed)") from None
            stderr.seek(0)
            err = stderr.read().decode(errors="replace").strip().splitlines()
        if status != 0:
            raise RuntimeError(f"command {self.argv[0]} exited with status {status}"
                               + (f": {err[-1]}" if err else ""))
