"""Alert and source plugins, found through entry points only.

A plugin is a class registered in one of two entry-point groups of its distribution's
``pyproject.toml`` (the built-ins in ``plugins/fault_screen_plugins`` register exactly so)::

    [project.entry-points."fault_screen.alerts"]
    pager = "my_site.alerts:Pager"
    [project.entry-points."fault_screen.sources"]
    mqtt = "my_site.sources:MqttSource"

The monitor never imports a plugin by module path; it asks
``importlib.metadata.entry_points(group=...)``.

Alert plugins (group ``fault_screen.alerts``)
    ``cls(**options)``; ``deliver(alert: dict) -> None`` hands one alert (the JSON-able dict
    of :func:`fault_screen.monitor.stage.alert_payload`; ``alert["id"]`` is its stable
    idempotency key) to the operator.  Raising any exception means "not delivered": the
    outbox retries later with backoff, with the same id; an exception with a true
    ``permanent`` attribute means "never deliverable" (the outbox dead-letters the alert and
    goes on).  Optional ``identity`` (str: what it delivers to, without secrets; the outbox
    keys its rows by it, so options such as retries may change across restarts) and
    ``close()``.

Source plugins (group ``fault_screen.sources``)
    ``cls(target: str, *, decoder, poll_interval: float, log: logging.Logger, **options)``;
    ``read(timeout: float) -> list`` returns the new samples
    (:class:`fault_screen.io.log_stream.Sample`, model-time seconds, SI), waiting up to
    ``timeout`` seconds for some; ``close()``.  Line-based sources hand each line to
    ``decoder.feed_line(text, line_number)`` (the replay format and its policies), and call
    ``decoder.new_file()`` after a rotation or truncation.

Options on the command line: ``--alert NAME[:CONFIG]`` where CONFIG is either a JSON object
(``webhook:{"url": "...", "secret_env": "FS_SECRET"}``), a JSON array (the ``argv`` of
``command``), ``key=value`` pairs separated by commas (``webhook:url=http://...,retries=3``),
or a single value for the plugin's ``main_option`` (``jsonl:alerts.jsonl``).
"""
from __future__ import annotations

import inspect
import json
import re
from importlib.metadata import entry_points
from typing import Dict

__all__ = ["GROUPS", "PluginError", "available", "load", "parse_config", "instantiate", "alert_sinks"]

GROUPS = {"alert": "fault_screen.alerts", "source": "fault_screen.sources"}


class PluginError(ValueError):
    """An unknown plugin name or bad plugin options; the message names them."""


def available(kind: str) -> Dict[str, object]:
    """Installed plugins of ``kind`` ("alert" or "source"): name -> entry point."""
    eps = entry_points(group=GROUPS[kind])
    found = {}
    for ep in eps:
        found.setdefault(ep.name, ep)   # the first distribution on the path wins, as for imports
    return dict(sorted(found.items()))


def load(kind: str, name: str):
    """The class registered as ``name`` in the ``kind`` group."""
    found = available(kind)
    if name not in found:
        supported = ", ".join(found) or "none installed"
        raise PluginError(f"unknown {kind} plugin {name!r}; supported: {supported}")
    try:
        return found[name].load()
    except Exception as exc:  # a broken third-party plugin must be named, not crash the monitor
        raise PluginError(f"{kind} plugin {name!r} ({found[name].value}) cannot be loaded: "
                          f"{type(exc).__name__}: {exc}") from None


_PAIR = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*=")


def parse_config(text: str | None, main_option: str | None = None) -> dict:
    """Options from the CONFIG part of ``NAME:CONFIG`` (see the module docstring)."""
    if text is None or text == "":
        return {}
    t = text.strip()
    if t.startswith("{") or t.startswith("["):
        try:
            val = json.loads(t)
        except json.JSONDecodeError as exc:
            # the options are not echoed: they may hold a URL with a token
            raise PluginError(f"options: not valid JSON ({exc.msg} at character {exc.pos + 1})") \
                from None
        except RecursionError:
            raise PluginError("options: JSON nested too deeply") from None
        if isinstance(val, list):
            return {"argv": val}
        return dict(val)
    parts = t.split(",")
    if all(_PAIR.match(p.strip()) for p in parts):
        out = {}
        for p in parts:
            k, v = p.strip().split("=", 1)
            out[k] = _scalar(v)
        return out
    if main_option is None:
        raise PluginError("options: give key=value pairs or a JSON object")
    return {main_option: t}


def _scalar(v: str):
    for conv in (int, float):
        try:
            return conv(v)
        except ValueError:
            pass
    return v


def instantiate(kind: str, spec: str, *args, **extra):
    """An instance of the plugin named by ``NAME[:CONFIG]``, called with ``args`` (a source's
    target), the CONFIG options and ``extra`` keyword arguments (a source's decoder, ...).
    Unknown names and bad options raise :class:`PluginError` naming them."""
    name, _, config = spec.partition(":")
    cls = load(kind, name)
    options = parse_config(config or None, getattr(cls, "main_option", None))
    try:
        inspect.signature(cls).bind(*args, **options, **extra)
    except TypeError as exc:
        known = [p for p in inspect.signature(cls).parameters
                 if p not in extra and p not in ("self", "args", "kwargs")][len(args):]
        raise PluginError(f"{kind} plugin {name!r}: {exc}; its options: "
                          f"{', '.join(known) or 'none'}") from None
    try:
        return cls(*args, **options, **extra)
    except (TypeError, ValueError, KeyError, OSError) as exc:
        raise PluginError(f"{kind} plugin {name!r}: {exc}") from None


def alert_sinks(specs) -> Dict[str, object]:
    """The alert plugins of ``--alert`` specs keyed by their identity (the plugin's
    ``identity``, else its name and options): what the outbox keys its rows by."""
    out = {}
    for spec in specs:
        sink = instantiate("alert", spec)
        out[str(getattr(sink, "identity", spec))] = sink
    return out
