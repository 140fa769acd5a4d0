"""A built model's Functions kept in the crashnlp cache: a process reads them instead of deriving
the model again.

Deriving a model (Lagrange's equations by AD, the front end's laws over every breakpoint) costs
every process that builds one, and every case of a study, tens of milliseconds, more with more
breakpoints; reading its Functions as CasADi serialized them a few (CHANGELOG.md). A stored model is keyed by what
fixes its expressions: its form's class, its Structure, its parameter layout, CasADi's version
and the source of every module that derives it (crashnlp.models and crashnlp.base.outputs), so
that a change to any of them derives it anew. What is read is the same Function to the last
bit (its serialization is the one stored), so the compiled libraries' keys
(crashnlp.numerics.compiled) and every result are the same as the derived model's. A file that
cannot be read or written is passed over: the model is derived, as without a cache.
"""

from __future__ import annotations

import hashlib
from contextlib import suppress
from functools import cache
from pathlib import Path

import casadi as ca

from crashnlp.base import outputs
from crashnlp.base.cache import KEPT_MODEL, cache_dir, files_digest, used, write_atomic


@cache
def _sources() -> str:
    """A digest of the source of the modules a model is derived by (read once per process)."""
    return files_digest(sorted(Path(__file__).parent.glob("*.py")) + [Path(outputs.__file__)])


def path_of(form: str, what: object) -> Path:
    """The cache file of the model of `form` whose expressions `what` fixes (the form's class,
    Structure and parameter layout, as a repr that names every field)."""
    key = hashlib.sha256("\0".join((repr(what), ca.CasadiMeta.version(), _sources())).encode()).hexdigest()[:20]
    return cache_dir() / KEPT_MODEL.format(form=form, key=key)


def read(path: Path) -> ca.Function | None:
    """The stored model (CrashModel.whole), marked used (the cache's limit removes the least
    recently used first), or None where there is none, or it cannot be read."""
    with suppress(OSError, RuntimeError):
        whole = ca.Function.deserialize(path.read_text())
        used(path)
        return whole
    return None


def write(path: Path, whole: ca.Function) -> None:
    """Keep a model (CrashModel.whole) for the next process (an unwritable cache only costs it a derivation)."""
    with suppress(OSError):
        write_atomic(path, whole.serialize())
