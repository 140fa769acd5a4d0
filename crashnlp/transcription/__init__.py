"""Transcriptions of the crash ODE into NLP variables and constraints.

Each is a subclass of `Transcription` registered in TRANSCRIPTIONS under the
`method` name used in problem files.
"""

from crashnlp.transcription.base import Trajectory, Transcription
from crashnlp.transcription.collocation import Collocation
from crashnlp.transcription.multiple_shooting import MultipleShooting

TRANSCRIPTIONS: dict[str, type[Transcription]] = {
    "multiple-shooting": MultipleShooting,
    "collocation": Collocation,
}


def make_transcription(model, spec) -> Transcription:
    """The transcription a problem's `transcription` section asks for."""
    return TRANSCRIPTIONS[spec.method](model, spec)


__all__ = ["TRANSCRIPTIONS", "Trajectory", "Transcription", "make_transcription"]
