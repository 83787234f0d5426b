"""Small JSON file helpers shared by the result types."""

from __future__ import annotations

import json
import os


def write_json_atomic(path: str | os.PathLike, data, *, overwrite: bool = False, indent: int | None = None) -> None:
    """Write ``data`` as JSON to ``path`` through a temporary file and a rename; refuse to overwrite unless asked."""
    path = os.fspath(path)
    if os.path.exists(path) and not overwrite:
        raise FileExistsError(f"{path} exists; pass overwrite=True to replace it")
    tmp = path + ".tmp"
    with open(tmp, "w", encoding="utf-8") as handle:
        json.dump(data, handle, indent=indent)
    os.replace(tmp, path)
