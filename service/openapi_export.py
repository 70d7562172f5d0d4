"""``python -m service.openapi_export openapi/openapi.json``: write the app's OpenAPI spec.

The bytes are canonical (sorted keys, two-space indent, final newline) so that a test can
compare the checked-in file with the app byte for byte.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any


def spec() -> dict[str, Any]:
    """The OpenAPI document of an app built with default settings (nothing is started)."""
    from service.config import Settings
    from service.main import create_app

    document: dict[str, Any] = create_app(Settings(api_keys=[])).openapi()
    return document


def render(document: dict[str, Any]) -> str:
    return json.dumps(document, indent=2, sort_keys=True, ensure_ascii=False) + "\n"


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    target = Path(args[0]) if args else Path("openapi/openapi.json")
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text(render(spec()), encoding="utf-8")
    print(f"wrote {target}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
