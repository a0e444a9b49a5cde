"""Alert plugins found through entry points: signed webhooks with retries against a local
receiver, JSON lines, commands; the durable outbox across restarts."""
from __future__ import annotations

import base64
import hashlib
import hmac
import json
import sys
import time

import pytest

from fault_screen.monitor import plugins
from fault_screen.monitor.outbox import Outbox
from monitor_fakes import Receiver


# the plugins are found by their entry points (tests/monitor/conftest.py)
pytestmark = pytest.mark.usefixtures("dist")


def test_builtins_are_registered_and_unknown_names_list_them():
    assert list(plugins.available("alert")) == ["command", "jsonl", "webhook"]
    assert list(plugins.available("source")) == ["csv", "hydws", "stdin"]
    with pytest.raises(plugins.PluginError, match=r"unknown alert plugin 'pager'; supported: "
                                                  r"command, jsonl, webhook"):
        plugins.load("alert", "pager")
    with pytest.raises(plugins.PluginError, match=r"'webhook'.*unexpected keyword.*retries"):
        plugins.instantiate("alert", "webhook:url=http://x,colour=red")


def test_config_forms():
    assert plugins.parse_config("alerts.jsonl", "path") == {"path": "alerts.jsonl"}
    assert plugins.parse_config("url=http://h:1/a,retries=3,backoff=0.5") == {
        "url": "http://h:1/a", "retries": 3, "backoff": 0.5}
    assert plugins.parse_config('["/bin/echo", "a b"]') == {"argv": ["/bin/echo", "a b"]}
    assert plugins.parse_config('{"url": "http://h/?a=1,b=2"}') == {"url": "http://h/?a=1,b=2"}
    with pytest.raises(plugins.PluginError, match="shell string"):
        plugins.instantiate("alert", "command:/bin/echo hello")


# ---- webhook ---------------------------------------------------------------------------------
# the Standard Webhooks specification's published test vector
VECTOR = dict(secret="whsec_MfKQ9r8GKYqrTwjUPD8ILPZIo2LaLaSw", id="msg_p5jXN8AQM9LWM0D4loKWxJek",
              ts=1614265330, body=b'{"test": 2432232314}',
              sig="v1,g0hM9SsE+OTPJTGt/tmIKtSyZlE3uFJELVlNIOLJ1OE=")


def reference_signature(secret: str, msg_id: str, ts: str, body: bytes) -> str:
    """Written from the Standard Webhooks text, independently of the plugin."""
    key = base64.standard_b64decode(secret.split("_", 1)[1] if secret.startswith("whsec_")
                                    else secret)
    mac = hmac.new(key, digestmod=hashlib.sha256)
    mac.update(f"{msg_id}.{ts}.".encode())
    mac.update(body)
    return "v1," + base64.standard_b64encode(mac.digest()).decode("ascii")


def test_signature_matches_the_published_vector():
    from fault_screen_plugins.alerts import secret_key, sign

    assert reference_signature(VECTOR["secret"], VECTOR["id"], str(VECTOR["ts"]),
                               VECTOR["body"]) == VECTOR["sig"]
    for secret in (VECTOR["secret"], VECTOR["secret"][len("whsec_"):]):
        assert sign(secret_key(secret), VECTOR["id"], VECTOR["ts"], VECTOR["body"]) == \
            VECTOR["sig"]


ALERT = {"id": "fs_0123456789abcdef", "level": "red", "previous_level": "yellow",
         "level_code": 2, "previous_level_code": 1, "rule": "max_utilisation > 1.0",
         "action": "stop injection and bleed off", "metrics": {"max_utilisation": 1.02},
         "model_time": 735.0, "wall_time": "2026-01-01T00:00:00+00:00", "scene": "x"}


def test_webhook_retries_refusals_and_every_attempt_is_signed(monkeypatch):
    secret = "whsec_" + base64.b64encode(b"a 32-byte key for the test hook!").decode()
    monkeypatch.setenv("FS_TEST_SECRET", secret)
    rx = Receiver([503, 503])
    try:
        hook = plugins.instantiate(
            "alert", f"webhook:url={rx.url},secret_env=FS_TEST_SECRET,retries=3,backoff=0.05")
        t0 = time.time()
        hook.deliver(ALERT)
    finally:
        rx.close()
    assert len(rx.requests) == 3
    for headers, body, when in rx.requests:
        assert headers["webhook-id"] == ALERT["id"]               # same key on every attempt
        assert json.loads(body) == ALERT
        ts = headers["webhook-timestamp"]
        assert abs(int(ts) - when) <= 2
        assert headers["webhook-signature"] == reference_signature(secret, ALERT["id"], ts, body)
    # exponential backoff: 0.05 s then 0.1 s between attempts (sleeps are lower bounds)
    gaps = [rx.requests[i + 1][2] - rx.requests[i][2] for i in range(2)]
    assert gaps[0] >= 0.05 and gaps[1] >= 0.1
    assert rx.requests[0][2] >= t0


def test_webhook_gives_up_on_a_client_error_and_names_a_missing_secret(monkeypatch):
    rx = Receiver([400])
    try:
        hook = plugins.instantiate("alert", f"webhook:url={rx.url},retries=3,backoff=0.01")
        with pytest.raises(RuntimeError, match="HTTP 400, not retried"):
            hook.deliver(ALERT)
    finally:
        rx.close()
    assert len(rx.requests) == 1
    monkeypatch.delenv("FS_NOT_SET", raising=False)
    with pytest.raises(plugins.PluginError, match="FS_NOT_SET"):
        plugins.instantiate("alert", "webhook:url=http://127.0.0.1:9/x,secret_env=FS_NOT_SET")


def test_command_gets_the_alert_on_stdin_and_in_the_environment(tmp_path):
    out = tmp_path / "got.json"
    script = ("import json, os, sys; d = json.load(sys.stdin); "
              f"open({str(out)!r}, 'w').write(json.dumps([d, os.environ['FAULT_SCREEN_LEVEL'], "
              "json.loads(os.environ['FAULT_SCREEN_ALERT'])['id']]))")
    hook = plugins.instantiate("alert", "command:" + json.dumps([sys.executable, "-c", script]))
    hook.deliver(ALERT)
    d, level, aid = json.loads(out.read_text())
    assert d == ALERT and level == "red" and aid == ALERT["id"]
    failing = plugins.instantiate("alert", "command:" + json.dumps(
        [sys.executable, "-c", "import sys; sys.exit('pager down')"]))
    with pytest.raises(RuntimeError, match="status 1: pager down"):
        failing.deliver(ALERT)


# ---- outbox ----------------------------------------------------------------------------------
class Flaky:
    """An alert sink that is down until ``up`` is set; records what it received."""

    def __init__(self):
        self.up = False
        self.got = []

    def deliver(self, alert):
        if not self.up:
            raise ConnectionError("receiver down")
        self.got.append(alert["id"])


def test_outbox_keeps_undelivered_alerts_across_a_restart(tmp_path):
    path = tmp_path / "box.sqlite"
    sink = Flaky()
    box = Outbox(path, {"hook": sink}, backoff=0.01)
    ids = [f"fs_{k}" for k in range(5)]
    for i in ids[:3]:
        box.put(dict(ALERT, id=i))
    assert box.deliver_due() == 0 and box.pending() == 3
    sink.up = True
    time.sleep(0.02)
    assert box.deliver_due() == 3
    sink.up = False
    for i in ids[3:]:
        box.put(dict(ALERT, id=i))
    box.deliver_due()
    box.close()                                    # the process ends with two undelivered

    sink2 = Flaky()
    sink2.up = True
    box = Outbox(path, {"hook": sink2}, backoff=0.01)
    # the restarted monitor recomputes alerts it had already stored: same ids, ignored
    assert box.put(dict(ALERT, id=ids[1])) == 0 and box.put(dict(ALERT, id=ids[4])) == 0
    assert box.pending() == 2
    time.sleep(0.02)
    assert box.drain(timeout=5.0) == 0
    box.close()
    # no loss, no duplicate, in the order raised
    assert sink.got + sink2.got == ids
    rows = Outbox(path, {"hook": sink2}).rows()
    assert sorted(r["id"] for r in rows) == ids and all(r["delivered"] for r in rows)


def test_outbox_backoff_doubles_and_holds_later_alerts(tmp_path):
    now = [1000.0]
    sink = Flaky()
    box = Outbox(tmp_path / "b.sqlite", {"hook": sink}, backoff=2.0, max_backoff=5.0,
                 clock=lambda: now[0])
    box.put(dict(ALERT, id="a"))
    box.put(dict(ALERT, id="b"))
    tries = []
    for _ in range(4):
        box.deliver_due()
        tries.append(box.next_due() - now[0])
        now[0] = box.next_due()
    assert tries == [2.0, 4.0, 5.0, 5.0]             # 2 s, 4 s, then capped at 5 s
    assert [r["attempts"] for r in box.rows()] == [4, 0]   # "b" waits behind "a"
    sink.up = True
    assert box.deliver_due() == 2 and sink.got == ["a", "b"]
    box.close()


def test_jsonl_appends_one_line_per_alert(tmp_path):
    hook = plugins.instantiate("alert", f"jsonl:{tmp_path / 'alerts.jsonl'}")
    hook.deliver(ALERT)
    hook.deliver(dict(ALERT, id="fs_2", metrics={"event_distance": None}))
    lines = (tmp_path / "alerts.jsonl").read_text().splitlines()
    assert [json.loads(x)["id"] for x in lines] == [ALERT["id"], "fs_2"]
    with pytest.raises(plugins.PluginError, match="does not exist"):
        plugins.instantiate("alert", f"jsonl:{tmp_path / 'no' / 'a.jsonl'}")
