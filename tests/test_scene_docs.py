"""docs/scenes.md stays true to the scene loader: its key tables name exactly the fields of
the config dataclasses with their defaults, its example scene loads, its list of shipped
scenes matches configs/scenes/."""

from __future__ import annotations

import dataclasses
import re
import tomllib
import types
import typing
from pathlib import Path
from typing import Any

from haptic_local_model.shared import config
from haptic_local_model.shared.config import CONFIG_ROOT, SceneConfig, load_config_text

DOC = Path(__file__).resolve().parent.parent / "docs" / "scenes.md"
KEYS_MARKER = re.compile(r"^<!-- keys: (\w+) -->$", re.M)
KEY_ROW = re.compile(r"^\|\s*`(\w+)`\s*\|([^|]*)\|([^|]*)\|")
#: default cells that are not TOML literals
NO_DEFAULT, UNSET, TABLE_DEFAULTS = "required", "unset", "defaults"


def doc_text() -> str:
    return DOC.read_text()


def table_after(text: str, marker: str) -> list[str]:
    """The markdown table rows (header and rule included) right after `marker`."""
    start = text.index(marker) + len(marker)
    rows = []
    for line in text[start:].lstrip("\n").splitlines():
        if not line.startswith("|"):
            break
        rows.append(line)
    assert rows, f"{DOC.name}: no table after {marker!r}"
    return rows


def key_tables(text: str) -> dict[str, dict[str, tuple[str, str]]]:
    """Class name -> {key: (type cell, default cell)} for every `<!-- keys: Class -->` table."""
    tables: dict[str, dict[str, tuple[str, str]]] = {}
    for found in KEYS_MARKER.finditer(text):
        name = found.group(1)
        assert name not in tables, f"{DOC.name}: two key tables for {name}"
        rows = {}
        for line in table_after(text, found.group(0))[2:]:
            row = KEY_ROW.match(line)
            assert row, f"{DOC.name}, {name} table: a row without a `key` first: {line!r}"
            key = row.group(1)
            assert key not in rows, f"{DOC.name}, {name} table: `{key}` listed twice"
            rows[key] = (row.group(2).strip(), row.group(3).strip())
        tables[name] = rows
    return tables


def nested_dataclasses(cls: Any) -> set[Any]:
    """`cls` and every dataclass its fields hold, however nested (tuples, dicts, unions)."""
    seen: set[Any] = set()
    todo = [cls]
    while todo:
        tp = todo.pop()
        if dataclasses.is_dataclass(tp) and isinstance(tp, type):
            if tp not in seen:
                seen.add(tp)
                todo.extend(typing.get_type_hints(tp).values())
        elif typing.get_origin(tp) is not None or isinstance(tp, types.UnionType):
            todo.extend(a for a in typing.get_args(tp) if a is not Ellipsis)
    return seen


SCENE_CLASSES = sorted(nested_dataclasses(SceneConfig), key=lambda c: c.__name__)


def as_tuples(value: Any) -> Any:
    return tuple(as_tuples(v) for v in value) if isinstance(value, list) else value


def documented_default(cell: str, where: str) -> Any:
    """The default a cell states: a TOML literal in backticks, or one of the words."""
    if cell in (NO_DEFAULT, UNSET, TABLE_DEFAULTS):
        return cell
    literal = re.fullmatch(r"`(.+)`", cell)
    assert literal, f"{where}: default {cell!r} is neither a `TOML literal` nor a keyword"
    return as_tuples(tomllib.loads(f"v = {literal.group(1)}")["v"])


def code_default(f: dataclasses.Field[Any]) -> Any:
    if f.default is not dataclasses.MISSING:
        return UNSET if f.default is None else f.default
    if f.default_factory is not dataclasses.MISSING:
        made = f.default_factory()
        return TABLE_DEFAULTS if dataclasses.is_dataclass(made) else made
    return NO_DEFAULT


def test_every_scene_dataclass_has_a_key_table() -> None:
    """SceneConfig and every dataclass nested in it (Material, BodySpec, ...) are documented."""
    documented = set(key_tables(doc_text()))
    missing = {c.__name__ for c in SCENE_CLASSES} - documented
    assert not missing, f"{DOC.name}: no `<!-- keys: X -->` table for {sorted(missing)}"


def test_every_key_table_names_exactly_the_fields() -> None:
    """Each table lists every field of its class, and nothing that is not a field."""
    problems = []
    for name, rows in key_tables(doc_text()).items():
        cls = getattr(config, name, None)
        if not (isinstance(cls, type) and dataclasses.is_dataclass(cls)):
            problems.append(f"{name}: not a dataclass of shared/config.py")
            continue
        fields = {f.name for f in dataclasses.fields(cls)}
        if undocumented := sorted(fields - set(rows)):
            problems.append(f"{name}: fields missing from its table: {undocumented}")
        if unknown := sorted(set(rows) - fields):
            problems.append(f"{name}: table keys that are not fields: {unknown}")
    assert not problems, f"{DOC.name} drifted from shared/config.py:\n" + "\n".join(problems)


def test_every_documented_default_is_the_codes() -> None:
    problems = []
    for name, rows in key_tables(doc_text()).items():
        cls = getattr(config, name)
        for f in dataclasses.fields(cls):
            if f.name not in rows:
                continue  # reported by the test above
            where = f"{DOC.name}, {name}.{f.name}"
            stated = documented_default(rows[f.name][1], where)
            if stated != code_default(f):
                problems.append(f"{where}: doc says {stated!r}, code has {code_default(f)!r}")
    assert not problems, "\n".join(problems)


def example_scene(text: str) -> str:
    found = re.search(r"<!-- example-scene -->\s*```toml\n(.*?)```", text, re.S)
    assert found, f"{DOC.name}: no ```toml block after <!-- example-scene -->"
    return found.group(1)


def test_the_example_scene_loads() -> None:
    """The example is a complete scene: the project's loader accepts it as it is."""
    scene = load_config_text(SceneConfig, example_scene(doc_text()), f"{DOC.name} example")
    assert scene.all_bodies  # crowds expand here, outside the loader's checks


def test_the_shipped_scenes_are_listed_with_their_descriptions() -> None:
    rows = table_after(doc_text(), "<!-- shipped-scenes -->")[2:]
    listed = {}
    for line in rows:
        cells = [c.strip() for c in line.strip("|").split("|")]
        listed[cells[0].strip("`")] = cells[1]
    shipped = {p.stem: p for p in sorted((CONFIG_ROOT / "scenes").glob("*.toml"))}
    assert sorted(listed) == sorted(shipped), f"{DOC.name}: shipped-scenes table is stale"
    for stem, path in shipped.items():
        description = tomllib.loads(path.read_text())["description"]
        assert listed[stem] == description, f"{DOC.name}: {stem}'s description differs"
