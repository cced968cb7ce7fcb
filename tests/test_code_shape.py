"""The code stays in the shape the redesign gave it: short functions with few parameters
(groups travel as records), and a tick that reads as a list of stage calls."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("shared", "sim_server", "haptic_server", "device_models")
MAX_LINES = 120  # a function longer than this does several jobs
MAX_PARAMETERS = 8  # beyond this, a group of arguments is a record


def functions() -> list[tuple[str, ast.FunctionDef | ast.AsyncFunctionDef]]:
    found = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                    found.append((f"{path.relative_to(ROOT)}:{node.lineno} {node.name}", node))
    return found


def parameters(node: ast.FunctionDef | ast.AsyncFunctionDef) -> list[str]:
    a = node.args
    names = [x.arg for x in (*a.posonlyargs, *a.args, *a.kwonlyargs)]
    return [n for n in names if n not in ("self", "cls")] + ([a.vararg.arg] if a.vararg else [])


@pytest.mark.slow
def test_no_function_is_long_or_takes_many_parameters() -> None:
    long = []
    wide = []
    for where, node in functions():
        lines = (node.end_lineno or node.lineno) - node.lineno + 1
        if lines > MAX_LINES:
            long.append(f"{where}: {lines} lines")
        if len(parameters(node)) > MAX_PARAMETERS:
            wide.append(f"{where}: {len(parameters(node))} parameters")
    assert not long and not wide, long + wide


def test_the_tick_is_a_list_of_stage_calls() -> None:
    """haptic_tick only unpacks its records and calls stages; no method branches in it."""
    tree = ast.parse((ROOT / "haptic_server" / "stages" / "tick.py").read_text())
    tick = next(n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "haptic_tick")
    body = tick.body[1:]  # after the docstring
    calls = [s for s in body if isinstance(s, ast.Expr) and isinstance(s.value, ast.Call)]
    others = [s for s in body if not isinstance(s, ast.Assign) and s not in calls]
    assert len(calls) >= 8 and not others, ast.unparse(tick)
    assert "method" not in ast.unparse(tick)


@pytest.mark.parametrize("package", ["shared", "haptic_server"])
def test_no_positional_wire_offsets(package: str) -> None:
    """Contact columns and limits are read by name, never as fl[c + 10] or limits[9]."""
    positional = re.compile(r"fl\[c \+ |limits\[[1-9]")
    for path in (ROOT / package).rglob("*.py"):
        assert not positional.search(path.read_text()), path
