"""The names a problem file chooses among, one per registry: the names here, below the
schema, and the implementations above it, keyed by these names.

The schema takes its choices from these without importing the layers that implement
them (CasADi's, the readers'), and the command line its `--format` choices without importing
the schema (crashnlp.problem.schema); hence the lowest layer. tests/test_registries.py holds each implementation registry to
its names. Adding a law or a data format is its implementation, its entry in the implementation
registry, and its name here. The model forms' registry is crashnlp.problem.forms; a transcription's
name is its spec class's `method` in the schema (each has fields of its own), held to
crashnlp.transcription.TRANSCRIPTIONS by the same test.
"""

from __future__ import annotations

SPRING_LAWS = {"force": "N", "secant": "N/m"}  # name -> the SI unit of its values; crashnlp.models.laws.SPRING_LAWS
UNLOADING_LAWS = ("elastic", "plastic")  # crashnlp.models.laws.UNLOADING_LAWS
DATA_FORMATS = ("csv", "nhtsa-ev5", "nhtsa-channel", "iso-mme")  # crashnlp.data.load.READERS
