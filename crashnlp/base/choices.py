"""The names a problem file chooses among, one per registry: the names here, below the
schema, and the implementations above it, keyed by these names.

The schema takes its choices from these without importing the layers that implement
them (CasADi's, the readers', the executors'), and the command line its `--format` and
`--executor` choices without importing the schema (crashnlp.problem.schema); hence the lowest
layer. tests/test_registries.py holds each implementation registry to its names. Adding a law,
a data format or a design objective is its implementation, its entry in the implementation
registry, and its name here; adding a filter class is its entry here alone (its frequency). The
model forms' registry is crashnlp.problem.forms; a transcription's name is its spec class's
`method` in the schema (each has fields of its own), held to crashnlp.transcription.TRANSCRIPTIONS
by the same test.
"""

from __future__ import annotations

SPRING_LAWS = {"force": "N", "secant": "N/m"}  # name -> the SI unit of its values; crashnlp.models.laws.SPRING_LAWS
UNLOADING_LAWS = ("elastic", "plastic")  # crashnlp.models.laws.UNLOADING_LAWS
DATA_FORMATS = ("csv", "nhtsa-ev5", "nhtsa-channel", "iso-mme")  # crashnlp.data.load.READERS
# SAE J211's channel frequency classes: name -> its class (Hz), which crashnlp.data.signal filters at
CFC_CLASSES = {"CFC60": 60.0, "CFC180": 180.0, "CFC600": 600.0, "CFC1000": 1000.0}
EXECUTORS = ("local", "dask")  # where tasks run: crashnlp.engine.executors.make_executor
DESIGN_OBJECTIVES = ("peak_decel", "olc", "crush")  # crashnlp.optimize.design.DESIGN_OBJECTIVES; the first the default
