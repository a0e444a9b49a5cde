"""Alert delivery against hostile receivers on 127.0.0.1: redirects are never followed, refusals
are dead-lettered without blocking later alerts, red overtakes yellow, a hung receiver delays no
other sink, a command's delivery is its own exit status, outbox rows survive a change of options,
and secrets are never shown, stored or passed on."""
from __future__ import annotations

import base64
import json
import logging
import os
import signal
import socket
import sys
import time

import pytest
from click.testing import CliRunner

from fault_screen.monitor import plugins
from fault_screen.monitor.outbox import Outbox
from monitor_fakes import Receiver


# the plugins are found by their entry points (tests/monitor/conftest.py)
pytestmark = pytest.mark.usefixtures("dist")


def alert(aid, level):
    code = {"green": 0, "yellow": 1, "red": 2}[level]
    return {"id": aid, "level": level, "level_code": code, "previous_level": "green",
            "previous_level_code": 0, "rule": "r", "action": "", "metrics": {},
            "model_time": 1.0, "wall_time": "2026-01-01T00:00:00+00:00", "scene": "x"}


def test_a_redirect_is_never_followed_and_the_outbox_keeps_the_alert(monkeypatch, caplog):
    """301/302/303/307/308: one POST, nothing reaches the redirect's target (no GET without
    body counted as delivered, no signature sent on), deliver() raises naming the redirect, the
    alert stays pending."""
    monkeypatch.setenv("FS_RX_SECRET", "whsec_" + base64.b64encode(b"k" * 32).decode())
    target = Receiver()
    try:
        for code in (301, 302, 303, 307, 308):
            rx = Receiver([code], location=target.url)
            try:
                hook = plugins.instantiate(
                    "alert", f"webhook:url={rx.url},secret_env=FS_RX_SECRET,retries=2,backoff=0.01")
                box = Outbox(":memory:", {"hook": hook}, backoff=10.0)
                box.put(alert(f"fs_{code}", "red"))
                with caplog.at_level(logging.WARNING):
                    assert box.deliver_due() == 0
                assert box.pending() == 1 and box.dead() == 0
                [row] = box.rows()
                assert f"HTTP {code} redirect" in row["last_error"] and "not followed" in row["last_error"]
                assert rx.methods == ["POST"]        # not retried, not re-sent
                box.close()
            finally:
                rx.close()
        assert target.requests == []
        assert "redirect" in caplog.text and "not followed" in caplog.text
    finally:
        target.close()


def test_a_refused_alert_is_dead_lettered_reported_and_blocks_nothing(tmp_path, caplog):
    """A 400 is a permanent failure: dead letter at once (logged as an error, counted, listed by
    'fault-screen plugins --outbox'), and the next alert of the same level is delivered."""
    from fault_screen.cli import main

    rx = Receiver([400])
    try:
        hook = plugins.instantiate("alert", f"webhook:url={rx.url},retries=3,backoff=0.01")
        path = tmp_path / "box.sqlite"
        box = Outbox(path, {"hook": hook}, backoff=0.01)
        box.put(alert("fs_refused", "yellow"))
        with caplog.at_level(logging.ERROR):
            box.deliver_due()
        box.put(alert("fs_next", "yellow"))
        assert box.deliver_due() == 1
        assert rx.ids() == ["fs_refused", "fs_next"]        # the refusal was not retried
        assert box.pending() == 0 and box.dead() == 1
        assert "fs_refused" in caplog.text and "refused for good" in caplog.text
        box.close()
    finally:
        rx.close()
    out = CliRunner().invoke(main, ["plugins", "--outbox", str(path)])
    assert out.exit_code == 0, out.output
    assert "hook: 0 pending, 1 delivered, 1 refused for good" in out.output
    assert "dead letter fs_refused (level 1)" in out.output and "HTTP 400" in out.output


def test_red_overtakes_a_yellow_waiting_for_its_retry(tmp_path):
    """A yellow answered 503 waits for its retry; a later red is delivered meanwhile, the later
    yellow waits behind the first (alerts of one level keep the order raised)."""
    now = [1000.0]
    rx = Receiver([503])
    try:
        hook = plugins.instantiate("alert", f"webhook:url={rx.url},retries=0")
        box = Outbox(tmp_path / "b.sqlite", {"hook": hook}, backoff=5.0, clock=lambda: now[0])
        box.put(alert("fs_yellow", "yellow"))
        assert box.deliver_due() == 0                 # 503: the yellow waits 5 s
        box.put(alert("fs_red", "red"))
        box.put(alert("fs_yellow_2", "yellow"))
        assert box.deliver_due() == 1                 # the red goes past; yellows keep their order
        assert box.next_due() == now[0] + 5.0
        now[0] += 5.0
        assert box.deliver_due() == 2
        box.close()
    finally:
        rx.close()
    assert rx.ids() == ["fs_yellow", "fs_red", "fs_yellow", "fs_yellow_2"]


def test_a_hung_receiver_delays_no_other_sink(tmp_path):
    """A receiver that accepts connections and never answers holds its own worker only: the
    JSON-lines sink gets the alert while the webhook's attempt is still waiting."""
    hung = socket.socket()
    hung.bind(("127.0.0.1", 0))
    hung.listen(8)                    # the kernel accepts; nobody answers
    try:
        url = f"http://127.0.0.1:{hung.getsockname()[1]}/hook"
        hook = plugins.instantiate("alert", f"webhook:url={url},retries=0,timeout=60")
        lines = tmp_path / "alerts.jsonl"
        jsonl = plugins.instantiate("alert", f"jsonl:{lines}")
        # the hung sink first: a single deliverer would reach the file only after 60 s
        box = Outbox(tmp_path / "b.sqlite", {"hook": hook, "file": jsonl})
        box.put(alert("fs_1", "red"))       # stored before the deliverers start: no race
        box.start()
        deadline = time.monotonic() + 30.0          # guards the test against a hang only
        while box.pending() == 2 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert json.loads(lines.read_text())["id"] == "fs_1"
        rows = {r["sink"]: r for r in box.rows()}
        assert rows["file"]["delivered"] is not None
        assert rows["hook"]["delivered"] is None and rows["hook"]["attempts"] == 0   # still waiting
        box.close()
    finally:
        hung.close()


def test_a_pager_that_leaves_a_background_child_is_delivered_once(tmp_path):
    """The command exits 0 at once but its child keeps the inherited descriptors open for
    60 s: delivered, once, without waiting for the child."""
    runs = tmp_path / "runs.txt"
    script = ("import subprocess, sys; "
              "child = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)']); "
              f"open({str(runs)!r}, 'a').write(str(child.pid) + '\\n')")
    pager = plugins.instantiate("alert", "command:" + json.dumps(
        {"argv": [sys.executable, "-c", script], "timeout": 20}))
    box = Outbox(tmp_path / "b.sqlite", {"pager": pager})
    try:
        box.put(alert("fs_page", "red"))
        assert box.deliver_due() == 1
        [row] = box.rows()
        assert row["attempts"] == 1 and row["delivered"] is not None
    finally:
        box.close()
        for pid in runs.read_text().split():
            try:
                os.kill(int(pid), signal.SIGKILL)
            except ProcessLookupError:
                pass
    assert len(runs.read_text().split()) == 1


def test_outbox_rows_survive_a_restart_with_other_options(tmp_path):
    """Rows are keyed by what a sink delivers to: a restart with retries=2 instead of 1 (other
    option text, same URL) delivers every alert stored before."""
    rx = Receiver([503] * 6)
    path = tmp_path / "box.sqlite"
    try:
        sinks = plugins.alert_sinks([f"webhook:url={rx.url},retries=1,backoff=0.01"])
        box = Outbox(path, sinks, backoff=0.01)
        ids = [f"fs_{k}" for k in range(3)]
        for i in ids:
            box.put(alert(i, "yellow"))
        box.deliver_due()
        assert box.pending() == 3
        box.close()
        rx.codes.clear()
        sinks = plugins.alert_sinks([f"webhook:url={rx.url},retries=2,backoff=0.01"])
        box = Outbox(path, sinks, backoff=0.01)
        assert box.pending() == 3
        assert box.drain(timeout=30.0) == 0
        box.close()
    finally:
        rx.close()
    assert [i for i in rx.ids() if i not in ids] == [] and set(rx.ids()) == set(ids)
    assert rx.ids()[-3:] == ids


def test_secrets_are_never_shown_stored_or_passed_on(tmp_path, monkeypatch, caplog):
    """The webhook secret's variable is not in a command's environment; a token in the URL's
    path or query is in no log line, no error, no outbox row and no byte of the outbox file."""
    monkeypatch.setenv("FS_HOOK_SECRET", "whsec_" + base64.b64encode(b"s" * 32).decode())
    rx = Receiver([500] * 4)
    try:
        url = f"{rx.url}/T0001/B0002/s3cr3tT0ken?token=abc123xyz"
        sinks = plugins.alert_sinks([
            f"webhook:url={url},secret_env=FS_HOOK_SECRET,retries=1,backoff=0.01",
            "command:" + json.dumps([sys.executable, "-c",
                                     "import json, os; open(os.environ['FS_ENV_OUT'], 'w')"
                                     ".write(json.dumps(sorted(os.environ)))"])])
        monkeypatch.setenv("FS_ENV_OUT", str(tmp_path / "env.json"))
        path = tmp_path / "box.sqlite"
        box = Outbox(path, sinks, backoff=0.01)
        box.put(alert("fs_s", "red"))
        with caplog.at_level(logging.DEBUG):
            box.deliver_due()
            hook = next(s for s in sinks.values() if hasattr(s, "url"))
            with pytest.raises(RuntimeError) as err:
                hook.deliver(alert("fs_t", "red"))
        shown = " ".join([caplog.text, str(err.value), repr(hook), json.dumps(box.rows()),
                          " ".join(sinks)])
        box.close()
    finally:
        rx.close()
    assert len(rx.requests) == 4 and "HTTP 500" in shown         # the hook was tried and failed
    for token in ("s3cr3tT0ken", "abc123xyz", "T0001"):
        assert token not in shown
        for f in tmp_path.glob("box.sqlite*"):
            assert token.encode() not in f.read_bytes(), f.name
    env = json.loads((tmp_path / "env.json").read_text())
    assert "FAULT_SCREEN_ALERT" in env and "FS_HOOK_SECRET" not in env


@pytest.mark.parametrize("spec, message", [
    ('webhook:{"url": "https://hooks.example/T1/s3cr3tT0ken"', "not valid JSON"),
    ("webhook:" + "[" * 100000, "nested too deeply"),
    ("webhook:url=https://hooks.example/T1/s3cr3tT0ken,retries=x", "invalid literal"),
    ("webhook:ftp://hooks.example/T1/s3cr3tT0ken", "must start with http"),
])
def test_bad_alert_options_are_refused_without_echoing_a_token(spec, message):
    with pytest.raises(plugins.PluginError, match=message) as err:
        plugins.instantiate("alert", spec)
    assert "s3cr3tT0ken" not in str(err.value) and "\n" not in str(err.value)
