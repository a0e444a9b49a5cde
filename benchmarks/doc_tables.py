"""Benchmark tables written into the documentation (docs/performance/*.md), never by hand.

A benchmark calls :func:`write` with its markdown table; the page says which command wrote it and
under what load, so a reader can judge the wall times. The site includes these files as they are.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parents[1] / "docs" / "performance"


def _command() -> str:
    """The command line of the running benchmark script, as a reader would type it from the
    repository root (a script in a folder under benchmarks/ keeps its folder)."""
    script = Path(sys.argv[0]).resolve()
    try:
        name = script.relative_to(DOCS.parents[1]).as_posix()
    except ValueError:      # run from a copy elsewhere: its name under benchmarks/
        name = "benchmarks/" + script.name
    return "python " + " ".join([name, *sys.argv[1:]])


def write(name: str, title: str, intro: str, table: list[str], load_start: float) -> Path:
    """Write ``docs/performance/<name>.md``: a title, the command that made it, the machine's
    cores and load, ``intro`` and the table's lines."""
    command = _command()
    page = [
        f"# {title}",
        "",
        f"Written by `{command}` (do not edit: run the script again). Measured on "
        f"{os.cpu_count()} cores; 1-minute load average {load_start:.1f} at the start and "
        f"{os.getloadavg()[0]:.1f} at the end: on a shared machine every wall time grows with the "
        "load, so compare rows of one run.",
        "",
        intro,
        "",
        *table,
        "",
    ]
    DOCS.mkdir(parents=True, exist_ok=True)
    path = DOCS / f"{name}.md"
    path.write_text("\n".join(page), encoding="utf-8")
    return path


README = Path(__file__).resolve().parents[1] / "README.md"


def write_readme(name: str, table: list[str], load_start: float) -> Path:
    """Put ``table`` into README.md between ``<!-- table: NAME -->`` and ``<!-- /table: NAME -->``
    (the markers stay; what is between them is replaced), with the command and the load, so the
    README's figures come from the same run as the docs page's."""
    command = _command()
    begin, end = f"<!-- table: {name} -->", f"<!-- /table: {name} -->"
    text = README.read_text(encoding="utf-8")
    if begin not in text or end not in text:
        raise SystemExit(f"README.md has no {begin} ... {end} markers")
    head, rest = text.split(begin, 1)
    _, tail = rest.split(end, 1)
    body = [f"Written by `{command}` on {os.cpu_count()} cores, load average {load_start:.1f} at the "
            f"start and {os.getloadavg()[0]:.1f} at the end.", "", *table]
    README.write_text(head + begin + "\n" + "\n".join(body) + "\n" + end + tail, encoding="utf-8")
    return README
