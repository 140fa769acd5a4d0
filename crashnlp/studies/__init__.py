"""Constraint what-if studies: one base problem, some entries varied, every case solved.

`run_study` solves the cases in parallel (on crashnlp.engine's executors), each
warm-started from a neighbour fixed in advance, and writes a table and figures.
Submodules load on first use, so that the command line starts quickly.
"""

from importlib import import_module

_EXPORTS = {
    "run_study": "crashnlp.studies.run",
    "Study": "crashnlp.studies.spec",
    "StudySpec": "crashnlp.studies.spec",
    "load_study": "crashnlp.studies.spec",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(import_module(_EXPORTS[name]), name)
    raise AttributeError(name)
