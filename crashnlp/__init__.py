"""crashnlp: frontal-crash models (pendulum, rigid body, engine on mounts), identified and designed by NLP.

The Python API (crashnlp.api): `load`, `identify`, `design`, `simulate`,
`compare`, `study`, and the plain `Result` they return. They are imported on first use,
so the command line starts without them; `dir(crashnlp)` (tab completion) and `help(crashnlp)`
list them all the same.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from crashnlp.base import VERSION

__version__ = VERSION
__all__ = ["Result", "compare", "design", "identify", "load", "simulate", "study"]

if TYPE_CHECKING:
    from crashnlp.api import compare, design, identify, load, simulate, study
    from crashnlp.results.result import Result


def __dir__() -> list[str]:
    """The API's names (and the version), which tab completion and help() list: not the module's
    own imports."""
    return sorted([*__all__, "__version__"])


def __getattr__(name: str) -> Any:
    if name == "Result":
        from crashnlp.results.result import Result

        return Result
    if name in __all__:
        import crashnlp.api

        return getattr(crashnlp.api, name)
    raise AttributeError(f"module 'crashnlp' has no attribute {name!r}")
