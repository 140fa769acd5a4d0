"""Optimal control on the crash model: identification (fit to data) and design (no data)."""

from __future__ import annotations

import sys
from typing import TextIO

import numpy as np

from crashnlp.case import Case
from crashnlp.optimize.identify import Solution, identify


def solve_case(
    case: Case, verbose: bool = False, progress: TextIO | None = sys.stdout, warm: np.ndarray | None = None
) -> Solution:
    """Solve a case as its problem's `kind` says (identify or design)."""
    if case.problem.kind == "design":
        from crashnlp.optimize.design import design

        return design(case, verbose=verbose, progress=progress, warm=warm)
    return identify(case, verbose=verbose, progress=progress, warm=warm)


__all__ = ["Solution", "solve_case"]
