"""Events, command answers and stroke rows as compact JSON text (``std_msgs/String`` data).

Numbers stay numbers (numpy's scalars and arrays as Python's), a set or tuple a list, anything
else its text: the same bytes whether the node publishes a row live or ``mps track`` writes it
into a recording.
"""

from __future__ import annotations

import json
from typing import Any

__all__ = ["to_json"]


def _plain(v: Any) -> Any:
    if hasattr(v, "tolist"):  # numpy scalars and arrays
        return v.tolist()
    if isinstance(v, set | tuple):
        return list(v)
    return str(v)


def to_json(obj: Any) -> str:
    """Return ``obj`` as compact JSON text (see the module)."""
    return json.dumps(obj, default=_plain, separators=(",", ":"))
