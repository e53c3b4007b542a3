"""Export the bake config's JSON Schema to ``proto/schema/bake-config.schema.json``.

Run ``python -m proto.export_schema`` (or ``kiln schema --out FILE``); a test fails when the
committed file differs from the model.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

from proto.models import BakeConfig

SCHEMA_PATH = Path(__file__).parent / "schema" / "bake-config.schema.json"


def schema_text() -> str:
    schema = BakeConfig.model_json_schema()
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["$id"] = "https://kiln.invalid/schema/bake-config.schema.json"
    return json.dumps(schema, indent=2, sort_keys=True) + "\n"


if __name__ == "__main__":
    SCHEMA_PATH.write_text(schema_text())
    print(f"wrote {SCHEMA_PATH}", file=sys.stderr)
