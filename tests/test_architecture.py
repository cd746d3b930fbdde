"""The dependency direction of ARCHITECTURE.md §2, checked on the source.

executive.core imports nothing above it; behaviours and sim2d import only executive.core
(and themselves); behaviours never imports sim2d. Checked with the AST, so a violation
anywhere (even inside a function) fails here rather than in review.
"""

import ast
from pathlib import Path

import pytest

from tests.conftest import REPO

ALLOWED = {
    "executive/core": ("executive.core",),
    "behaviours": ("behaviours", "executive.core"),
    "sim2d": ("sim2d", "executive.core"),
}
OURS = ("executive", "behaviours", "sim2d", "tests")


def _imports(path: Path) -> list[tuple[int, str]]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.append((node.lineno, node.module))
    return found


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_package_imports_only_what_it_may(package):
    allowed = ALLOWED[package]
    bad = []
    for path in sorted((REPO / package).rglob("*.py")):
        for line, module in _imports(path):
            if module.split(".")[0] not in OURS:
                continue  # third-party or standard library
            if not any(module == a or module.startswith(a + ".") for a in allowed):
                bad.append(f"{path.relative_to(REPO)}:{line} imports {module}")
    assert not bad, "\n".join(bad)
