"""References generated from the code at build time, so they cannot go stale.

MkDocs loads this file as a hook (``mkdocs.yml``: ``hooks``). ``on_files`` adds four pages that
exist only in the built site:

- ``reference/scene.md``: every scene key from the scene dataclasses (section, key, SI unit,
  physical and plausible range from ``fault_screen.scene.RANGES``, default, and the field's
  docstring);
- ``reference/results.md``: every HDF5 dataset from ``fault_screen.outputs.SCHEMA``;
- ``reference/cli.md``: ``--help`` of every click command and the exit codes as
  ``fault_screen.cli._options`` decides them;
- ``changelog.md``: the repository's ``CHANGELOG.md``.

``tests/docs/test_docs.py`` imports the same functions and checks what they produce against the code.
"""
from __future__ import annotations

import ast
import re
import dataclasses
import inspect
import textwrap
import typing
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


# ---------------------------------------------------------------------------- scene reference
def field_docs(cls) -> dict[str, str]:
    """The docstring under each field of a dataclass (the string literal that follows it)."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    body = tree.body[0].body
    docs = {}
    for node, nxt in zip(body, body[1:] + [None]):
        if (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)
                and isinstance(nxt, ast.Expr) and isinstance(nxt.value, ast.Constant)
                and isinstance(nxt.value.value, str)):
            docs[node.target.id] = " ".join(inspect.cleandoc(nxt.value.value).split())
    return docs


def _nested(cls, name: str):
    """The dataclass a field holds, itself or as the items of a tuple, else None."""
    hint = typing.get_type_hints(cls)[name]
    candidates = [hint, *typing.get_args(hint)]
    for c in list(candidates):
        candidates += typing.get_args(c)
    for c in candidates:
        if isinstance(c, type) and dataclasses.is_dataclass(c):
            return c
    return None


def _default(f: dataclasses.Field):
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return dataclasses.MISSING


def _cell(text) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _value(v) -> str:
    if v is dataclasses.MISSING:
        return "required"
    if v is None:
        return "unset"
    if isinstance(v, float):
        return f"{v:g}"
    if isinstance(v, str):
        return f'"{v}"'
    return str(v)


#: units a field's docstring may name in brackets, e.g. "Domain width (m)."
_DOC_UNIT = re.compile(r"\((m|m\^2|m/s|m/Pa|Pa|Pa/m|Pa s|s|kg/m\^3|degrees|m\^2/\(Pa s\)|1/h|m3/s)\)")


def doc_unit(doc: str) -> str | None:
    """The first unit a docstring names in brackets, in the references' spelling."""
    m = _DOC_UNIT.search(doc)
    if m is None:
        return None
    return {"degrees": "deg", "m^2": "m2", "kg/m^3": "kg/m3", "m^2/(Pa s)": "m2/(Pa s)"}.get(m[1], m[1])


def field_unit(key: str, name: str, doc: str, kinds: set) -> str:
    """The SI unit of a scene key: its range's, its quantity's, or the one its docstring names."""
    from fault_screen import scene
    from fault_screen.units import SI_UNIT

    if name == "schedule":
        return "[s, m3/s] (rate control) or [s, Pa] (pressure control)"
    if kinds <= {str, bool, dict}:
        return ""  # a word, a switch or a table: no unit
    if key in scene.RANGES:
        return scene.RANGES[key][0]
    quantity = scene.QUANTITY.get(name)
    if quantity == "angle":
        return "deg"
    if quantity in SI_UNIT:
        return SI_UNIT[quantity]
    return doc_unit(doc) or "-"


def scene_rows() -> list[dict]:
    """One row per scene key: section, key, unit, physical range, plausible range, default, doc."""
    from fault_screen.scene import RANGES, Scene

    rows = []

    def walk(cls, section: str):
        docs = field_docs(cls)
        hints = typing.get_type_hints(cls)
        subsections = []
        for f in dataclasses.fields(cls):
            sub = _nested(cls, f.name)
            if sub is not None:
                many = typing.get_origin(typing.get_type_hints(cls)[f.name]) is tuple
                name = f"{section}.{f.name}" if section else f.name
                subsections.append((sub, f"[{name}]" if many else name))
                continue
            default = _default(f)
            key = f"{section.split('.')[0].strip('[]')}.{f.name}"
            if section.startswith(("[zones]", "damage_zone")) and f"rock.{f.name}" in RANGES:
                key = f"rock.{f.name}"
            doc = docs.get(f.name, "")
            kinds = {a for a in (typing.get_args(hints[f.name]) or (hints[f.name],)) if a is not type(None)}
            unit = field_unit(key, f.name, doc, kinds)
            physical = plausible = ""
            if key in RANGES:
                _, (plo, phi), (qlo, qhi) = RANGES[key]
                physical, plausible = f"{plo:g} to {phi:g}", f"{qlo:g} to {qhi:g}"
            rows.append(dict(section=section or "(top level)", key=f.name, unit=unit,
                             physical=physical, plausible=plausible, default=_value(default),
                             doc=doc))
        for sub, name in subsections:
            walk(sub, name)

    walk(Scene, "")
    return rows


def scene_reference() -> str:
    lines = [
        "# Scene reference",
        "",
        "Generated at build time from the scene dataclasses (`fault_screen/scene.py`): every key a",
        "scene file may set, its SI unit, its physical range (outside it the scene is refused, exit 2)",
        "and plausible range (outside it the scene is accepted with a warning), its default and what",
        "it means. A value may be given in other units (see [Scenes](../scenes.md#units));",
        "`fault-screen scene show SCENE.toml` prints a scene resolved in these units.",
        "Sections written `[[name]]` are arrays of tables.",
    ]
    section = None
    for r in scene_rows():
        if r["section"] != section:
            section = r["section"]
            lines += ["", f"## `[{section}]`" if section != "(top level)" else "## Top level", "",
                      "| key | unit | physical range | plausible range | default | meaning |",
                      "|---|---|---|---|---|---|"]
        lines.append(f"| `{r['key']}` | {_cell(r['unit'])} | {r['physical']} | {r['plausible']} | "
                     f"{_cell(r['default'])} | {_cell(r['doc'])} |")
    return "\n".join(lines) + "\n"


# -------------------------------------------------------------------------- results reference
def results_reference() -> str:
    from fault_screen.outputs import markdown_table

    return "\n".join([
        "# Results reference",
        "",
        "Generated at build time from the output schema `fault_screen.outputs.SCHEMA`, which the HDF5",
        "writer reads too (`python -m fault_screen.outputs` prints the same table). Shapes: `(time, x)`",
        "along the fault's Gauss points at the profile times `/fault/time`, `(time,)` one value per",
        "step, `(x,)` fixed along the fault. See [Results](../results.md) for how the file is written.",
        "",
        markdown_table(),
    ]) + "\n"


# ------------------------------------------------------------------------------ CLI reference
def _commands(group, prefix):
    import click

    yield prefix, group
    if isinstance(group, click.Group):
        for name in group.list_commands(None):
            yield from _commands(group.get_command(None, name), f"{prefix} {name}")


def command_help(cmd, path: str) -> str:
    """``--help`` of a command as the terminal shows it (80 columns)."""
    import click

    parent = None
    for name in path.split()[:-1]:
        parent = click.Context(click.Command(name), info_name=name, parent=parent)
    ctx = click.Context(cmd, info_name=path.split()[-1], parent=parent, terminal_width=80,
                        max_content_width=80)
    return cmd.get_help(ctx)


def exit_codes() -> str:
    """The exit-code list of ``fault_screen.cli._options`` (the only place they are decided)."""
    from fault_screen.cli import _options

    doc = inspect.getdoc(_options)
    items = doc.split("Exit codes", 1)[1].split("\n\n", 2)[1]
    text = " ".join(items.split()).replace(" * ", "\n* ").replace("* ", "- ", 1).replace("\n* ", "\n- ")
    # Sphinx roles read as plain code in markdown: :class:`~a.b.Name` -> `Name`, ``x`` -> `x`
    text = re.sub(r":\w+:`~?(?:[\w.]*\.)?(\w+)`", r"`\1`", text)
    return text.replace("``", "`")


def cli_commands() -> list[tuple[str, object]]:
    from fault_screen.cli import main

    return list(_commands(main, "fault-screen"))


def cli_reference() -> str:
    lines = [
        "# CLI reference",
        "",
        "Generated at build time from the click commands (`fault_screen/cli/`): the `--help` of every",
        "command, as `fault-screen COMMAND --help` prints it.",
        "",
        "## Exit codes",
        "",
        exit_codes(),
    ]
    for path, cmd in cli_commands():
        lines += ["", f"## `{path}`", "", "```text", command_help(cmd, path), "```"]
    return "\n".join(lines) + "\n"


def changelog() -> str:
    return (ROOT / "CHANGELOG.md").read_text(encoding="utf-8")


GENERATED = {
    "reference/scene.md": scene_reference,
    "reference/results.md": results_reference,
    "reference/cli.md": cli_reference,
    "changelog.md": changelog,
}


# ----------------------------------------------------------------------------- the MkDocs hook
def on_files(files, config):
    from mkdocs.structure.files import File

    for uri, make in GENERATED.items():
        files.append(File.generated(config, uri, content=make()))
    return files
