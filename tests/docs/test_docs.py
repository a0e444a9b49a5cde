"""The documentation is executed and checked against the code and the runs.

- Every fenced ```bash and ```python block of README.md and docs/**/*.md (docs/incoming/ aside:
  notes waiting to be folded in) runs, page by page and in order, in one scratch folder where the
  repository's configs/ and benchmarks/ are at hand, as a user runs them from the repository
  root after ``pip install -e .``. A block that must not run (an install, a live monitor, a
  site's template) has the marker ``<!-- docs-test: skip (reason) -->`` on the line before it;
  the reason is required and the markers are few. A block that appears twice (the same run on two
  pages) runs once.
- Numbers quoted from runs are compared with the runs (README tour, monitoring example, the
  validation table's row of the scene the tour runs).
- The set-up commands are the ones .ci/run runs; the exit codes, the equation -> file -> test
  table and the generated references agree with the code.
"""
from __future__ import annotations

import ast
import importlib.util
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
SKIP = re.compile(r"<!-- docs-test: skip \((?P<reason>[^)]+)\) -->")
FENCE = re.compile(r"^```(?P<lang>[a-z]*)\n(?P<body>.*?)^```$", re.S | re.M)
#: the few blocks that must not run: installs (README, install page) and the live monitor
MAX_SKIPPED = 8


def pages() -> list[Path]:
    found = [ROOT / "README.md"] + sorted(p for p in DOCS.rglob("*.md") if "incoming" not in p.parts)
    return found


def blocks(page: Path) -> list[dict]:
    """The fenced blocks of a page: language, body, line, and the skip reason if marked."""
    text = page.read_text(encoding="utf-8")
    out = []
    for m in FENCE.finditer(text):
        line = text.count("\n", 0, m.start()) + 1
        before = text[:m.start()].rstrip("\n").rsplit("\n", 1)[-1]
        skip = SKIP.fullmatch(before.strip())
        out.append(dict(lang=m["lang"], body=m["body"], line=line,
                        skip=skip["reason"] if skip else None, marker=before.strip()))
    return out


def _page_id(page: Path) -> str:
    return str(page.relative_to(ROOT))


# ------------------------------------------------------------------------------ running blocks
class Workspace:
    """One scratch folder for the session; each distinct block runs once."""

    def __init__(self, path: Path):
        self.path = path
        for name in ("configs", "benchmarks"):
            (path / name).symlink_to(ROOT / name)
        self.env = dict(os.environ, MPLBACKEND="Agg", PYTHONUNBUFFERED="1",
                        PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}")
        self.done: dict[tuple[str, str], subprocess.CompletedProcess] = {}

    def run(self, lang: str, body: str) -> subprocess.CompletedProcess:
        key = (lang, body)
        if key not in self.done:
            cmd = ["bash", "-euo", "pipefail", "-c", body] if lang == "bash" else [sys.executable, "-c", body]
            self.done[key] = subprocess.run(cmd, cwd=self.path, env=self.env, capture_output=True, text=True,
                                            stdin=subprocess.DEVNULL)
        return self.done[key]

    def run_page(self, page: Path) -> list[tuple[dict, subprocess.CompletedProcess]]:
        """Run a page's examples in order; a shell block command by command (a backslash continues a
        line), so that a command two pages share runs once."""
        ran = []
        for b in blocks(page):
            if b["lang"] not in ("bash", "python") or b["skip"] is not None:
                continue
            units = commands(b["body"]) if b["lang"] == "bash" else [b["body"]]
            ran += [(dict(b, body=u), self.run(b["lang"], u)) for u in units]
        return ran


def commands(script: str) -> list[str]:
    """The commands of a shell block: its lines with continuations joined, comments and blanks left out."""
    joined = script.replace("\\\n", " ")
    return [line.strip() for line in joined.splitlines() if line.strip() and not line.lstrip().startswith("#")]


@pytest.fixture(scope="session")
def workspace(tmp_path_factory):
    return Workspace(tmp_path_factory.mktemp("docs-examples"))


@pytest.mark.parametrize("page", pages(), ids=_page_id)
def test_every_example_of_the_page_runs(page, workspace):
    for block, done in workspace.run_page(page):
        assert done.returncode == 0, (
            f"{_page_id(page)}:{block['line']}: the {block['lang']} example exits {done.returncode}\n"
            f"{block['body']}\n--- stdout\n{done.stdout[-3000:]}\n--- stderr\n{done.stderr[-3000:]}")


def test_skip_markers_are_few_and_say_why():
    marked = [(p, b) for p in pages() for b in blocks(p) if b["skip"] is not None]
    assert 0 < len(marked) <= MAX_SKIPPED, [f"{_page_id(p)}:{b['line']}" for p, b in marked]
    for p, b in marked:
        assert len(b["skip"].split()) >= 3, f"{_page_id(p)}:{b['line']}: say why the block does not run"
    # a marker that does not parse would silently run (or skip) the wrong block
    for p in pages():
        for b in blocks(p):
            if "docs-test" in b["marker"] and "skip" in b["marker"]:
                assert b["skip"] is not None, f"{_page_id(p)}:{b['line']}: malformed marker {b['marker']!r}"


def test_code_blocks_name_their_language():
    """A block without a language is neither run nor highlighted: say bash, python, toml or text."""
    for p in pages():
        for b in blocks(p):
            assert b["lang"], f"{_page_id(p)}:{b['line']}: a fenced block without a language"


# -------------------------------------------------------------------------- the set-up commands
def test_setup_commands_are_the_ones_ci_runs():
    setup = next(b for b in blocks(ROOT / "README.md") if b["lang"] == "bash")
    commands = [line.split("#")[0].strip() for line in setup["body"].splitlines()]
    assert commands == ['pip install -e . && fault-screen run',
                        'pip install -e ".[test]" && python -m pytest -q']
    ci = (ROOT / ".ci" / "run").read_text()
    ci_lines = [line.strip() for line in ci.splitlines() if not line.lstrip().startswith("#")]
    assert commands[1] in ci_lines
    assert 'pip install -e ".[docs]" && mkdocs build --strict' in ci_lines
    # the install page repeats the README's commands word for word
    install = next(b for b in blocks(DOCS / "install.md") if b["lang"] == "bash")
    assert install["body"] == setup["body"]


def test_readme_is_short():
    assert len((ROOT / "README.md").read_text().splitlines()) <= 200


def test_no_dates_times_or_revisions_in_the_prose():
    """History goes to CHANGELOG.md; the README and the site describe the code as it is. Examples
    (code blocks and inline code) may hold dates: a log's stamps, a --date option."""
    revision = r"\b(?=[0-9a-f]*[0-9])(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}\b"
    bad = re.compile(rf"\b20\d\d-\d\d-\d\d\b|\b\d\d:\d\d UTC\b|{revision}|last session|today's")
    for p in pages():
        if p.parent.name == "performance" and p.name != "index.md":
            continue  # written by the benchmark scripts
        prose = FENCE.sub(lambda m: "\n" * m.group(0).count("\n"), p.read_text())
        for n, line in enumerate(prose.splitlines(), 1):
            assert bad.search(re.sub(r"`[^`]*`", "", line)) is None, f"{_page_id(p)}:{n}: {line}"


# ------------------------------------------------------------------- numbers quoted from the runs
def _first_yellow(result) -> float:
    from fault_screen.ensemble import screening_summary

    return screening_summary(result)["time_first_yellow"]


def _tour_replay(workspace):
    from fault_screen.result import Result

    workspace.run_page(ROOT / "README.md")
    return Result.load(workspace.path / "replay.h5")


def test_readme_tour_numbers_are_the_replays(workspace):
    """The tour's impermeable replay: yellow at 390 s with the rule and action it names, and the
    peak overpressure to the digits quoted (the monitoring example once said 215 s)."""
    readme = (ROOT / "README.md").read_text()
    result = _tour_replay(workspace)
    quoted = {int(t) for t in re.findall(r"(?:yellow at|at model time)\s+(\d+) s", readme.replace("\n", " "))}
    assert quoted == {round(_first_yellow(result))} == {390}
    peak = re.search(r"peak overpressure at the injection point is\s+([\d.]+) MPa", readme.replace("\n", " "))
    assert peak is not None
    assert abs(float(peak[1]) - np.max(result.injection["overpressure"]) / 1e6) <= 0.0005
    first = result.extra["screening"]["transitions"][0]
    rule = first["rule"].decode() if isinstance(first["rule"], bytes) else str(first["rule"])
    assert (int(first["from"]), int(first["to"])) == (0, 1) and rule.startswith("near failure")
    assert "reduce the injection rate by half and watch the fault closely" in readme.replace("\n", " ")


def test_monitoring_example_number_is_the_replays(workspace):
    """A monitor over a complete log takes the steps of the replay of that log: the monitoring
    page's level change is the replay's first yellow."""
    text = (DOCS / "monitoring.md").read_text().replace("\n", " ")
    quoted = {int(t) for t in re.findall(r"At model time (\d+) s", text)}
    assert quoted == {round(_first_yellow(_tour_replay(workspace)))}


def _validation_rows() -> dict[str, list[str]]:
    text = (DOCS / "validation.md").read_text()
    table = text.split("<!-- docs-test: validation table", 1)[1]
    rows = {}
    for line in table.splitlines()[1:]:
        if not line.startswith("|"):
            if rows:
                break
            continue
        cells = [c.strip() for c in line.strip("|").split("|")]
        if cells[0] not in ("scene", "---"):
            rows[cells[0]] = cells[1:]
    return rows


def check_validation_row(cells: list[str], result) -> None:
    """One row of the validation table against its run, to the digits shown."""
    from fault_screen.budget import fluid_budget
    from fault_screen.ensemble import default_summary

    s = default_summary(result)
    peak, slip, onset, yellow, unknowns, budget = cells
    assert float(peak) == pytest.approx(s["peak_overpressure"] / 1e6, abs=0.0005)
    assert float(slip) == pytest.approx(s["injection_slip"] * 1e3, abs=0.0005)
    for shown, value in ((onset, s["slip_onset"]), (yellow, s["time_first_yellow"])):
        assert (shown == "-" and math.isnan(value)) or float(shown) == value
    assert int(unknowns) == s["unknowns"]
    assert budget == fluid_budget(result).summary()


def test_validation_table_row_of_the_tour_scene(workspace):
    """The impermeable (SI) row, from the `fault-screen run` that the README and the screening
    page make; the other rows are checked under -m validation (tests/validation)."""
    from fault_screen.result import Result

    workspace.run_page(DOCS / "screening.md")
    check_validation_row(_validation_rows()["impermeable"], Result.load(workspace.path / "impermeable.h5"))


# ------------------------------------------------------------------------ agreement with the code
def test_exit_codes_quoted_are_the_codes_the_cli_decides():
    from fault_screen.cli import _options

    doc = _options.__doc__.split("Exit codes", 1)[1]
    decided = {int(c) for c in re.findall(r"^\* (\d) --", doc, re.M)}
    assert decided == {0, 1, 2, 3, 4}
    for page in (DOCS / "cli.md", DOCS / "guide.md"):
        text = page.read_text().replace("\n", " ")
        quoted = re.search(r"0 success, 1 .*?, 2 .*?, 3 .*?, 4 ", text)
        assert quoted is not None, page


def test_equation_table_names_files_and_tests_that_exist():
    text = (DOCS / "theory.md").read_text()
    table = [line for line in text.split("## Equation, file, test", 1)[1].splitlines() if line.startswith("| Eq")]
    assert len(table) >= 9
    for line in table:
        file_cell, test_cell = line.strip("|").split("|")[2:4]
        for path in re.findall(r"`((?:physics|kernels)/[\w/]+\.py|[\w]+\.py)`", file_cell):
            assert (ROOT / "fault_screen" / path).is_file(), path
        tests = re.findall(r"`(tests/[\w/]+\.py)(?:::(\w+))?`", test_cell)
        assert tests, line
        tests += [(tests[-1][0], name) for name in re.findall(r"`::(\w+)`", test_cell)]
        # each test names its equation: the row's first number after "Eq." on its docstring's first line
        # (the module's docstring where the row names a whole file)
        equation = re.match(r"\| Eq\. (\d+)", line).group(1)
        for path, name in tests:
            tree = ast.parse((ROOT / path).read_text())
            node = next((f for f in tree.body if isinstance(f, ast.FunctionDef) and f.name == name), None)
            assert name == "" or node is not None, f"{path}::{name}"
            first = (ast.get_docstring(node or tree) or "").splitlines()[0:1]
            assert first and re.search(rf"\bEq\. [^:]*\b{equation}\b", first[0]), f"{path}::{name}"


def _hook():
    spec = importlib.util.spec_from_file_location("docs_reference_hook", DOCS / "hooks" / "reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_scene_reference_has_every_ranged_key_with_its_unit_and_range():
    from fault_screen.scene import RANGES

    rows = {(r["section"].split(".")[0], r["key"]): r for r in _hook().scene_rows()}
    checked = 0
    for key, (unit, (plo, phi), (qlo, qhi)) in RANGES.items():
        section, _, name = key.partition(".")
        if (section, name) not in rows:
            continue  # a schedule's columns and thresholds of other keys: not keys of their own
        r = rows[(section, name)]
        assert r["unit"] == unit, key
        assert r["physical"] == f"{plo:g} to {phi:g}" and r["plausible"] == f"{qlo:g} to {qhi:g}", key
        checked += 1
    assert checked >= 45
    # a few keys by hand: unit from the docstring's quantity, default, meaning
    assert rows[("fault", "friction")]["default"] == "0.61"
    assert rows[("time", "dt_max")]["default"] == "unset"
    assert rows[("mesh", "nx")]["doc"].startswith("Elements along x")


def test_scene_docstring_units_agree_with_the_ranges_and_quantities():
    """Where a field's docstring names its unit, the unit the scene validates and converts with is
    that one (a docstring saying (m) over a value read in Pa would mislead every reader)."""
    hook = _hook()
    named = [(r, hook.doc_unit(r["doc"])) for r in hook.scene_rows() if hook.doc_unit(r["doc"])]
    assert len(named) >= 40
    assert [(r["section"], r["key"], r["unit"], u) for r, u in named if u != r["unit"]] == []


def test_results_reference_is_the_output_schema():
    from fault_screen.outputs import SCHEMA, markdown_table

    page = _hook().results_reference()
    assert markdown_table() in page
    assert page.count("\n| `/") == len(SCHEMA)


def test_cli_reference_has_every_command_and_the_exit_codes():
    hook = _hook()
    page = hook.cli_reference()
    commands = [path for path, _ in hook.cli_commands()]
    assert {"fault-screen run", "fault-screen replay", "fault-screen monitor", "fault-screen screen",
            "fault-screen scene show", "fault-screen scene check"} <= set(commands)
    for path in commands:
        assert f"## `{path}`" in page
    assert page.count("Usage: ") == len(commands)
    codes = re.findall(r"^- (\d) -- ", page, re.M)
    assert codes == ["0", "1", "2", "3", "4"]


def _output_of(workspace, page: Path, command_start: str) -> subprocess.CompletedProcess:
    """What the page's command starting with ``command_start`` printed (the page's examples run first)."""
    for block, done in workspace.run_page(page):
        if block["body"].startswith(command_start):
            return done
    raise AssertionError(f"{_page_id(page)} has no example starting {command_start!r}")


def test_scene_page_fault_state_numbers_are_what_scene_check_prints(workspace):
    """Scenes: the fault-effective reading of Rustrel's stresses gives sigma'_n0 and the overpressure
    to failure the page quotes, as `fault-screen scene check` prints them."""
    text = (DOCS / "scenes.md").read_text().replace("\n", " ")
    quoted = re.search(r"give sigma'_n0 = ([\d.]+) MPa and ([\d.]+) MPa to failure as fault-effective", text)
    assert quoted is not None
    out = _output_of(workspace, DOCS / "scenes.md", "fault-screen scene check configs/rustrel-2015-calibrated").stdout
    assert re.search(rf"effective normal stress\s+{re.escape(quoted[1])} MPa", out), out
    assert f"overpressure to failure at the injection point: {quoted[2]} MPa" in out, out


def test_screening_page_exit_codes_are_the_commands(workspace):
    """The screening page says the impermeable run reaches yellow (exit 4 with --fail-on yellow) and
    not red (exit 0 with --fail-on red)."""
    page = DOCS / "screening.md"
    assert _output_of(workspace, page, "fault-screen screen impermeable.h5 --fail-on red").returncode == 0
    assert "exit code 4" in _output_of(workspace, page, "fault-screen screen impermeable.h5 --fail-on yellow").stdout


def test_readme_links_stay_in_the_repository_and_exist():
    """The README's links open files of the repository (the site's pages are checked by
    mkdocs build --strict); no link leaves it."""
    text = (ROOT / "README.md").read_text()
    links = re.findall(r"\]\(([^)]+)\)", text)
    assert len(links) >= 15
    for link in links:
        assert "://" not in link, link
        path = link.split("#", 1)[0]
        assert (ROOT / path).exists(), link


def test_cli_reference_help_is_what_help_prints():
    """The reference shows each command's --help as the command prints it (80 columns)."""
    from click.testing import CliRunner

    from fault_screen.cli import main

    hook = _hook()
    for path, cmd in hook.cli_commands():
        args = path.split()[1:] + ["--help"]
        printed = CliRunner().invoke(main, args, prog_name="fault-screen", terminal_width=80)
        assert printed.exit_code == 0, path
        assert printed.output == hook.command_help(cmd, path) + "\n", path


def _table_rows(text: str, first_cell: str) -> dict[str, list[str]]:
    """The rows of the markdown table whose header starts with ``first_cell``: first cell -> rest."""
    table = text.split(f"| {first_cell} |", 1)[1].split("\n\n", 1)[0].splitlines()[2:]
    return {cells[0]: cells[1:] for cells in ([c.strip() for c in row.strip("|").split("|")] for row in table)}


def test_screening_page_metrics_and_defaults_are_the_codes():
    """Every metric the rules may name is on the page with its unit, and the defaults table and
    the default rules are MonitorSpec's."""
    from fault_screen.rules import METRICS
    from fault_screen.scene import MonitorSpec

    text = (DOCS / "screening.md").read_text()
    listed = {}
    for names, cells in _table_rows(text, "metric").items():
        keys = re.findall(r"`(\w+)`", names)
        units = [u.strip() for u in cells[0].split(",")]
        listed.update(zip(keys, units * (len(keys) if len(units) == 1 else 1)))
    assert set(listed) == set(METRICS)
    for name, (unit, _) in METRICS.items():
        assert listed[name] == ("-" if unit == "1" else unit), name
    spec = MonitorSpec()
    shown = {re.sub(r"`", "", k): v[0] for k, v in _table_rows(text, "threshold").items()}
    assert set(shown) == {"slip_rate_yellow", "slip_rate_red", "utilisation_yellow", "magnitude_yellow",
                          "magnitude_red", "event_rate_window"}
    for name, cell in shown.items():
        assert float(re.search(r"[-\d.e]+(?=\s|$)", cell.replace("ML ", ""))[0]) == getattr(spec, name), name
    prose = " ".join(text.split("Default rules, in order:", 1)[1].split("\n\n", 1)[0].split())
    for rule in spec.rules:
        assert f"`{rule.name}` (`{rule.when}`)" in prose, rule.name
        assert f'"{rule.action}"' in prose, rule.action
    assert {r.hold for r in spec.rules if r.level == "red"} == {3600.0}
    assert {r.hold for r in spec.rules if r.level == "yellow"} == {600.0}
    assert "hold 1 h" in prose and "hold 10 min" in prose


def test_setup_command_runs_the_bundled_scene_from_an_empty_folder(tmp_path):
    """The README's first set-up command after its install: `fault-screen run` in a folder with
    nothing in it finds the bundled scene, writes its result there and ends with a verdict."""
    setup = next(b for b in blocks(ROOT / "README.md") if b["lang"] == "bash")
    command = setup["body"].splitlines()[0].split("#")[0].split("&&")[1].strip()
    assert command == "fault-screen run"
    env = dict(os.environ, MPLBACKEND="Agg",
               PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}")
    done = subprocess.run(command.split(), cwd=tmp_path, env=env, capture_output=True, text=True,
                          stdin=subprocess.DEVNULL)
    assert done.returncode == 0, done.stderr[-3000:]
    written = sorted(p.name for p in tmp_path.iterdir())
    assert len(written) == 1 and written[0].endswith(".h5"), written
    assert "verdict:" in done.stdout


def test_monitoring_example_logs_the_quoted_level_change(tmp_path):
    """The monitoring page's live example, on the whole log at once (the writer's speed-up aside):
    the monitor logs the level change the page quotes, at the model time it quotes, and the
    alert reaches alerts.jsonl."""
    import json
    import shutil

    page = (DOCS / "monitoring.md").read_text()
    live = next(b for b in blocks(DOCS / "monitoring.md") if b["skip"] is not None)
    command = commands(live["body"])[1]
    assert command.startswith("fault-screen monitor configs/rustrel-2015-impermeable.toml --follow live.csv")
    (tmp_path / "configs").symlink_to(ROOT / "configs")
    shutil.copy(ROOT / "configs" / "logs" / "rustrel-2015-standin.csv", tmp_path / "live.csv")
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}")
    done = subprocess.run(["bash", "-c", command.replace("--idle-exit 10", "--idle-exit 2")], cwd=tmp_path,
                          env=env, capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    quoted = re.search(r"At model time (\d+) s.*?`(level green -> yellow \(near failure\): [^`.]*)", page, re.S)
    assert f"t = {quoted[1]} s: {quoted[2]}" in done.stderr + done.stdout
    alerts = [json.loads(line) for line in (tmp_path / "alerts.jsonl").read_text().splitlines()]
    assert [a["level"] for a in alerts] == ["yellow"]


def test_forecast_page_table_is_what_the_command_prints(workspace):
    """Forecast: the table and the advice line the page quotes are the command's output, line for
    line (no wall times are printed, so the whole table is deterministic)."""
    page = DOCS / "forecast.md"
    printed = _output_of(workspace, page, "fault-screen forecast configs/rustrel-2015-impermeable.toml --at 5min")
    assert printed.returncode == 0, printed.stderr[-3000:]
    quoted = next(b["body"] for b in blocks(page) if b["lang"] == "text" and b["body"].startswith("made at"))
    lines = [" ".join(line.split()) for line in printed.stdout.splitlines()]
    for line in quoted.splitlines():
        assert " ".join(line.split()) in lines, line
    assert (workspace.path / "forecast.csv").is_file()
    assert (workspace.path / "figs" / "rustrel-2015-impermeable-forecast.png").is_file()
