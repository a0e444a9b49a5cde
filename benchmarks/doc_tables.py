"""Benchmark tables written into the documentation (docs/performance/*.md), never by hand.

A benchmark calls :func:`write` with its markdown table; the page says which command wrote it and
under what load, so a reader can judge the wall times. The site includes these files as they are.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parents[1] / "docs" / "performance"


def write(name: str, title: str, intro: str, table: list[str], load_start: float) -> Path:
    """Write ``docs/performance/<name>.md``: a title, the command that made it, the machine's
    cores and load, ``intro`` and the table's lines."""
    command = "python " + " ".join(["benchmarks/" + Path(sys.argv[0]).name, *sys.argv[1:]])
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
