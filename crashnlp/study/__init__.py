"""Constraint what-if studies: one base problem, some entries varied, every case solved.

`run_study` solves the cases in parallel (a local process pool or dask), each
warm-started from a neighbour fixed in advance, and writes a table and figures.
"""
from crashnlp.study.run import run_study
from crashnlp.study.spec import Study, StudySpec, load_study

__all__ = ["Study", "StudySpec", "load_study", "run_study"]
