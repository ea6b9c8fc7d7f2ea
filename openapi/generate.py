"""Write the app's OpenAPI document to ``openapi/openapi.json`` (``python -m openapi.generate``).

``tests/service/test_openapi.py`` fails when the committed file and the app disagree; rerun this
after an intended API change and commit the result.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

PATH = Path(__file__).resolve().parent / "openapi.json"


def render() -> str:
    """The app's OpenAPI document as stable, pretty JSON."""
    from service.app import create_app
    from service.settings import Settings

    doc = create_app(Settings()).openapi()
    return json.dumps(doc, indent=2, sort_keys=True, ensure_ascii=False) + "\n"


def main() -> int:
    PATH.write_text(render(), encoding="utf-8")
    print(f"wrote {PATH}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
