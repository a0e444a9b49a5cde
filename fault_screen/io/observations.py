"""Observed time series at the injection point, for calibration.

CSV with one header line; ``#`` lines and blank lines are comments (as injection logs). Columns,
matched on the header name without its unit, case-insensitively:

* time: ``time...`` / ``elapsed...``: ISO 8601 timestamps with a zone (model time 0 is the
  first stamp) or elapsed numbers in seconds or the header's unit (``elapsed[min]``);
* ``pressure`` (absolute pore pressure) or ``overpressure``: a pressure unit in the header;
* ``shear`` / ``slip`` / ``shear_displacement``: a length unit (``shear[mm]``);
* ``normal`` / ``opening`` / ``normal_displacement``: a length unit.

At least one observed column is needed. An empty cell means "not observed at that time" (the
column simply has no residual there). Problems raise :class:`ObservationsError` naming the file,
line and column.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

import numpy as np

from ..units import UnitError, parse_header, to_si
from .log_format import Numbers

_is_number = Numbers(",").ok  # the log reader's own test of a numeric cell (comma-separated files)

#: group -> (accepted column names, quantity, Result.injection key for each name)
GROUPS = {
    "pressure": ({"pressure": "pressure", "overpressure": "overpressure"}, "pressure"),
    "shear": ({"shear": "slip", "slip": "slip", "shear_displacement": "slip"}, "length"),
    "normal": ({"normal": "opening", "opening": "opening", "normal_displacement": "opening"}, "length"),
}


class ObservationsError(ValueError):
    """A problem in an observations file; the message names file, line and column."""


@dataclass(frozen=True)
class Observations:
    time: np.ndarray
    """Model time of each row (s)."""
    values: dict
    """group -> array of SI values (NaN where not observed)."""
    series: dict
    """group -> the Result.injection series it is compared with (pressure/overpressure, slip, opening)."""
    source: str = ""


def read_observations(path) -> Observations:
    path = Path(path)
    name = path.name
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ObservationsError(f"{path}: no such file") from None
    rows = [(i + 1, r) for i, r in enumerate(csv.reader(text.splitlines()))
            if r and any(c.strip() for c in r) and not r[0].lstrip().startswith("#")]
    if len(rows) < 2:
        raise ObservationsError(f"{name}: needs a header and at least one row")
    hline, header = rows[0]
    cols = [(raw.strip(),) + parse_header(raw) for raw in header]
    time_col = next((j for j, (_, base, _) in enumerate(cols)
                     if base.strip().lower().startswith(("time", "elapsed"))), None)
    if time_col is None:
        raise ObservationsError(f"{name} line {hline}: no time column (time... or elapsed...)")
    picked = {}
    for j, (raw, base, unit) in enumerate(cols):
        key = base.strip().lower()
        for group, (names, quantity) in GROUPS.items():
            if key in names:
                if group in picked:
                    raise ObservationsError(f"{name} line {hline}, column {raw}: a second {group} column")
                if unit is None:
                    raise ObservationsError(f"{name} line {hline}, column {raw}: give the unit in the "
                                            f"header, e.g. {base}[{'MPa' if quantity == 'pressure' else 'mm'}]")
                try:
                    factor = to_si(1.0, unit, quantity)
                except UnitError as exc:
                    raise ObservationsError(f"{name} line {hline}, column {raw}: {exc}") from None
                picked[group] = (j, factor, names[key], raw)
    if not picked:
        raise ObservationsError(f"{name} line {hline}: no observed column (pressure/overpressure, "
                                f"shear/slip, normal/opening)")
    t_raw, t_base, t_unit = cols[time_col]
    times, values = [], {g: [] for g in picked}
    t0 = None
    for line, row in rows[1:]:
        if len(row) != len(header):
            raise ObservationsError(f"{name} line {line}: {len(row)} cells, the header has {len(header)}")
        cell = row[time_col].strip()
        try:
            if t_unit is not None or _is_number(cell):
                t = to_si(float(cell), t_unit or "s", "time")
            else:
                stamp = datetime.fromisoformat(cell.replace("Z", "+00:00"))
                if stamp.tzinfo is None:
                    raise ObservationsError(f"{name} line {line}, column {t_raw}: {cell!r} has no time zone")
                t0 = t0 or stamp
                t = (stamp - t0).total_seconds()
        except (ValueError, UnitError) as exc:
            if isinstance(exc, ObservationsError):
                raise
            raise ObservationsError(f"{name} line {line}, column {t_raw}: bad time {cell!r}") from None
        if times and t <= times[-1]:
            raise ObservationsError(f"{name} line {line}, column {t_raw}: time {cell!r} does not increase")
        times.append(t)
        for group, (j, factor, _, raw) in picked.items():
            c = row[j].strip()
            if not c:
                values[group].append(math.nan)
                continue
            try:
                v = float(c)
            except ValueError:
                raise ObservationsError(f"{name} line {line}, column {raw}: {c!r} is not a number") from None
            if not math.isfinite(v):
                raise ObservationsError(f"{name} line {line}, column {raw}: {c!r} is not finite")
            values[group].append(v * factor)
    return Observations(time=np.array(times), values={g: np.array(v) for g, v in values.items()},
                        series={g: picked[g][2] for g in picked}, source=str(path))

