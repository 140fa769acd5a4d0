"""JSON files written atomically, with values cleaned for JSON (light: no model imports)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from crashnlp.results.files import atomic_open


def clean(value: Any) -> Any:
    """JSON-safe: numpy to Python, NaN to null, floats to 10 significant digits."""
    if isinstance(value, dict):
        return {str(k): clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [clean(v) for v in value]
    if isinstance(value, (np.floating, float)):
        v = float(value)
        return None if not math.isfinite(v) else float(f"{v:.10g}")
    if isinstance(value, np.integer):
        return int(value)
    return value


def json_text(obj: Any) -> str:
    """The text `write_json` writes of `obj` (cleaned, indented, a final line end)."""
    return json.dumps(clean(obj), indent=2) + "\n"


def write_json(path: Path, obj: Any) -> None:
    """Write JSON atomically (a reader never sees half a file), mode 0666 less the umask."""
    with atomic_open(path) as fh:
        fh.write(json_text(obj))
