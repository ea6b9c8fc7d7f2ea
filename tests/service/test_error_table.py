"""Every error code the service answers or stores comes from the one table (service/errors.py)."""

from __future__ import annotations

import ast
from pathlib import Path

from service.errors import API_ERRORS, JOB_ERRORS

ROOT = Path(__file__).resolve().parents[2]


def _calls(name: str):
    for path in [*ROOT.joinpath("service").rglob("*.py"), *ROOT.joinpath("worker").rglob("*.py")]:
        tree = ast.parse(path.read_text(), str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Call):
                f = node.func
                fname = f.id if isinstance(f, ast.Name) else getattr(f, "attr", None)
                if fname == name and node.args and isinstance(node.args[0], ast.Constant):
                    yield path.relative_to(ROOT), node.args[0].value
            if name == "dict" and isinstance(node, ast.Dict):
                for k, v in zip(node.keys, node.values, strict=True):
                    if (
                        isinstance(k, ast.Constant)
                        and k.value == "code"
                        and isinstance(v, ast.Constant)
                    ):
                        yield path.relative_to(ROOT), v.value


def test_api_error_codes_are_in_the_table():
    used = list(_calls("ApiError")) + list(_calls("error_body"))
    assert used
    assert [(p, c) for p, c in used if c not in API_ERRORS] == []


def test_job_error_codes_are_in_the_table():
    used = list(_calls("job_error"))
    assert {c for _, c in used} >= {"time_limit_exceeded", "too_many_attempts"}
    assert [(p, c) for p, c in used if c not in JOB_ERRORS] == []


def test_no_error_code_literals_outside_the_table():
    stray = [(str(p), c) for p, c in _calls("dict") if str(p) != "service/errors.py"]
    assert stray == []
