"""Docstring and function-length rules, checked on the source (AST: nothing is imported or compiled).

1. Every public function and class (name not starting with ``_``) of the packages in
   :data:`PACKAGES`, and every public method of a public class (dunders excepted), has a docstring.
   Add a package name to the tuple to extend the rule.
2. No function of ``magtune_core`` or ``ros2_ws/src`` is longer than :data:`MAX_LINES` lines unless
   it is numba-compiled (a decorator containing "jit": long straight-line loops are how numba code is
   written, one function per compiled unit).
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Packages under magtune_core whose public API must carry docstrings.
PACKAGES = ("ltp", "design", "sim", "bags")
#: Longest function body (def line to last line) allowed outside numba.
MAX_LINES = 100
#: Trees scanned for long functions (ros2_ws's build and install copies are skipped).
LENGTH_ROOTS = ("magtune_core", "ros2_ws/src")
SKIP_PARTS = {"build", "install", "log", "__pycache__"}


def _modules(base: Path):
    """Python files under base, excluding generated copies."""
    for path in sorted(base.rglob("*.py")):
        if not SKIP_PARTS.intersection(path.relative_to(ROOT).parts):
            yield path


def _tree(path: Path) -> ast.Module:
    return ast.parse(path.read_text(encoding="utf-8"), filename=str(path))


def _public(name: str) -> bool:
    return not name.startswith("_")


def undocumented(path: Path, root: Path = ROOT) -> list[str]:
    """``file:line name`` of each public function, class and public method of a public class without a
    docstring (module level; nested functions are implementation details)."""
    rel = path.relative_to(root)
    missing = []
    for node in _tree(path).body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and _public(node.name):
            if ast.get_docstring(node) is None:
                missing.append(f"{rel}:{node.lineno} {node.name}")
            if isinstance(node, ast.ClassDef):
                for item in node.body:
                    if (isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef)) and _public(item.name)
                            and ast.get_docstring(item) is None):
                        missing.append(f"{rel}:{item.lineno} {node.name}.{item.name}")
    return missing


def _jitted(node) -> bool:
    return any("jit" in ast.unparse(d) for d in node.decorator_list)


def long_functions(path: Path, limit: int = MAX_LINES, root: Path = ROOT) -> list[str]:
    """``file:line name (N lines)`` of each function (methods and nested ones included) longer than
    ``limit`` lines that is not numba-compiled."""
    rel = path.relative_to(root)
    out = []
    for node in ast.walk(_tree(path)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            n = node.end_lineno - node.lineno + 1
            if n > limit and not _jitted(node):
                out.append(f"{rel}:{node.lineno} {node.name} ({n} lines)")
    return out


@pytest.mark.parametrize("package", PACKAGES)
def test_public_api_has_docstrings(package):
    base = ROOT / "magtune_core" / package
    assert base.is_dir(), base
    missing = [m for path in _modules(base) for m in undocumented(path)]
    assert not missing, "public functions/classes/methods without a docstring:\n" + "\n".join(missing)


def test_no_long_functions_outside_numba():
    found = [m for r in LENGTH_ROOTS if (ROOT / r).is_dir() for path in _modules(ROOT / r) for m in long_functions(path)]
    assert not found, f"functions longer than {MAX_LINES} lines (not numba-compiled):\n" + "\n".join(found)


def test_the_checks_see_what_they_should(tmp_path):
    """The two scanners on a synthetic module: a missing docstring of a function, a class and a public
    method is reported, private names and dunders are not; a long plain function is, a long @njit one
    and one of exactly MAX_LINES lines are not."""
    src = tmp_path / "mod.py"
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_LINES))  # def + docstring + body: MAX_LINES + 2 lines
    limit = "\n".join(f"    x{i} = {i}" for i in range(MAX_LINES - 2))  # exactly MAX_LINES lines: allowed
    src.write_text(f'''
def f():
    pass

def _g():
    pass

class C:
    def m(self):
        pass

    def __len__(self):
        return 0

    def _p(self):
        pass

class D:
    """documented"""

    def m(self):
        """documented"""

@njit(cache=True)
def long_jit():
    """documented"""
{body}

def long_plain():
    """documented"""
{body}

def at_the_limit():
    """documented"""
{limit}
''')
    assert [m.split(" ", 1)[1] for m in undocumented(src, root=tmp_path)] == ["f", "C", "C.m"]
    assert [m.split(" ")[1] for m in long_functions(src, root=tmp_path)] == ["long_plain"]
