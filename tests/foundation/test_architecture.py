"""Sizes a reader can hold in mind (../shared/STYLE.md: no 1,600-line scripts, no module doing five
things): no source file over 800 lines, no function over 150. Numba kernels (``@njit``, ``@jit``)
are exempt: a kernel is one loop that is compiled as a whole, and splitting it costs speed.

Import cycles are kept out by import-linter's ``acyclic_siblings`` contract (pyproject.toml,
checked in ``test_layers.py``)."""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ["artitwin", "artitwin_core", "flows", "tasks", "infra", "schemas"]
MAX_FILE_LINES = 800
MAX_FUNCTION_LINES = 150


def _sources() -> list[Path]:
    return sorted(p for pkg in PACKAGES for p in (REPO / pkg).rglob("*.py") if "__pycache__" not in p.parts)


def _jitted(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    for dec in fn.decorator_list:
        target = dec.func if isinstance(dec, ast.Call) else dec
        name = target.attr if isinstance(target, ast.Attribute) else getattr(target, "id", "")
        if name in ("njit", "jit"):
            return True
    return False


def test_no_source_file_is_over_800_lines():
    long = [f"{p.relative_to(REPO)}: {n} lines" for p in _sources() if (n := len(p.read_text().splitlines())) > MAX_FILE_LINES]
    assert not long, "split these along their seams into private modules of one concern each:\n" + "\n".join(long)


def test_no_function_is_over_150_lines():
    long = []
    for path in _sources():
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and not _jitted(node):
                n = node.end_lineno - node.lineno + 1
                if n > MAX_FUNCTION_LINES:
                    long.append(f"{path.relative_to(REPO)}:{node.lineno} {node.name}: {n} lines")
    assert not long, "split these into steps that each do one thing:\n" + "\n".join(long)


def test_the_size_checks_see_a_long_function():
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_FUNCTION_LINES))
    fn = ast.parse(f"def f():\n{body}\n").body[0]
    assert fn.end_lineno - fn.lineno + 1 > MAX_FUNCTION_LINES and not _jitted(fn)
    jitted = ast.parse(f"@njit(cache=True)\ndef f():\n{body}\n").body[0]
    assert _jitted(jitted)
