"""A study folder's finished cases: cases/<id>.json (row + fingerprint) and cases/<id>.npy."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from crashnlp.base.outputs import current_names
from crashnlp.results.files import atomic_open, note_output
from crashnlp.results.jsonfile import write_json


class CaseStore:
    """cases/<id>.json (row + fingerprint) and cases/<id>.npy, each written atomically."""

    def __init__(self, folder: Path):
        self.folder = folder

    def row(self, case: str, key: str) -> dict | None:
        """The stored row of a finished case, if it was computed from the same inputs and is whole.

        A json that does not parse, lacks its row or status, or promises a solution vector whose
        .npy is missing, empty or corrupt marks the case unfinished: it is solved again.
        """
        path = self.folder / f"{case}.json"
        stored = _stored(path)
        if stored is None or stored.get("key") != key:
            return None
        row = stored["row"]
        if not self._whole(case, stored.get("vector", -1)):
            return None
        for kept in (path, self.folder / f"{case}.npy"):  # the study's output as much as a case it solves
            if kept.exists():
                note_output(kept)
        return row

    def _whole(self, case: str, size: int | None) -> bool:
        """Whether the solution vector a stored row promises (its size; None: none; -1: a row
        stored without its size, so the file's, if there) is there, whole."""
        if size is None:
            return True
        z = self.vector(case)
        if size == -1:
            return z is not None or not (self.folder / f"{case}.npy").exists()
        return z is not None and z.size == size

    def holds_any(self) -> bool:
        """Whether the folder holds a case's json (a run into it reuses or solves again its cases)."""
        return any(self.folder.glob("*.json"))

    def rows(self) -> list[dict]:
        """The row of every case stored whole, in case order, whatever inputs it was computed
        from: what the study's folder shows (its report)."""
        stored = (_stored(path) for path in sorted(self.folder.glob("*.json")))
        return [s["row"] for s in stored if s is not None]

    def vector(self, case: str) -> np.ndarray | None:
        """The stored solution vector, or None if there is none or it is not a whole finite vector."""
        path = self.folder / f"{case}.npy"
        try:
            z = np.load(path, allow_pickle=False)
        except (OSError, ValueError, EOFError):
            return None
        if z.ndim != 1 or z.dtype.kind != "f" or not np.all(np.isfinite(z)):
            return None
        return z

    def save(self, case: str, key: str, row: dict, z: np.ndarray | None) -> None:
        """Vector first, then the json that marks the case finished."""
        self.folder.mkdir(parents=True, exist_ok=True)
        npy = self.folder / f"{case}.npy"
        if z is not None:
            with atomic_open(npy, "wb") as fh:
                np.save(fh, np.asarray(z, dtype=float))
        else:
            npy.unlink(missing_ok=True)
        size = None if z is None else int(np.size(z))
        write_json(self.folder / f"{case}.json", {"key": key, "row": row, "vector": size})


def _stored(path: Path) -> dict | None:
    """A case's json, if it parses and holds a row with a status; else None (unfinished)."""
    try:
        stored = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):  # missing, unreadable, not UTF-8, not JSON
        return None
    if not isinstance(stored, dict):
        return None
    row = stored.get("row")
    if not (isinstance(row, dict) and isinstance(row.get("status"), str)):
        return None
    return {**stored, "row": current_names(row)}  # a case stored before a rename reads as one stored now
