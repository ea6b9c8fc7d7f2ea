"""Package structure: ``service`` owns the job logic and never imports ``worker``, which is
Celery wiring only (no package cycle)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _imports(path: Path) -> set[str]:
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            out.add(node.module)
    return out


def test_service_never_imports_worker():
    for path in (ROOT / "service").rglob("*.py"):
        bad = {m for m in _imports(path) if m == "worker" or m.startswith("worker.")}
        assert not bad, f"{path.relative_to(ROOT)} imports {bad}"


def test_worker_is_celery_wiring_only():
    """No database or job logic in ``worker/``: it calls ``service.fit_job``."""
    for path in (ROOT / "worker").rglob("*.py"):
        bad = {m for m in _imports(path) if m.split(".")[0] in ("sqlalchemy", "numpy", "core")}
        assert not bad, f"{path.relative_to(ROOT)} imports {bad}"
