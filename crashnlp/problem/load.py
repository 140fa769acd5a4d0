"""Read a YAML problem file into a validated `Problem`; bad input becomes one line."""

from __future__ import annotations

from collections.abc import Hashable
from pathlib import Path
from typing import Any

import yaml

from crashnlp.problem.errors import ProblemError
from crashnlp.problem.schema import Problem, problem_from_dict

MAX_ALIASES = 100  # YAML aliases in one file: a few share channel lists; thousands are a "billion laughs"


class UniqueKeyLoader(yaml.SafeLoader):
    """YAML's safe loader, refusing a mapping that gives a key twice (YAML would keep the last)
    and a file of more than MAX_ALIASES aliases (nested aliases expand exponentially)."""

    aliases = 0

    def compose_node(self, parent: yaml.Node | None, index: int) -> yaml.Node | None:
        if self.check_event(yaml.events.AliasEvent):
            self.aliases += 1
            if self.aliases > MAX_ALIASES:
                raise yaml.composer.ComposerError(None, None, f"more than {MAX_ALIASES} aliases", self.peek_event().start_mark)
        return super().compose_node(parent, index)

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Hashable, Any]:
        if isinstance(node, yaml.MappingNode):
            seen: set[Hashable] = set()
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    duplicate = key in seen
                except TypeError:  # an unhashable key: the base loader says so
                    break
                if duplicate:
                    raise yaml.constructor.ConstructorError(None, None, f"duplicate key {key!r}", key_node.start_mark)
                seen.add(key)
        return super().construct_mapping(node, deep)


def read_yaml(path: str | Path) -> dict[str, Any]:
    """Parse a YAML file, turning every read, encoding or syntax failure into a ProblemError."""
    path = Path(path)
    if not path.is_file():
        raise ProblemError(f"{path}: file not found")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise ProblemError(f"{path}: not valid UTF-8 text (byte {exc.start})") from None
    except OSError as exc:
        raise ProblemError(f"{path}: cannot read ({exc.strerror})") from None
    try:
        raw = yaml.load(text, Loader=UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or ""
        why = ": a tab, where YAML indents and separates with spaces" if "'\\t'" in problem else f": {problem}" if problem else ""
        raise ProblemError(f"{path}:{where} not valid YAML{why}") from None
    except RecursionError:
        raise ProblemError(f"{path}: not valid YAML (nested too deeply)") from None
    return raw


def check_fit_keys(problem: Problem, source: str | Path) -> None:
    """Refuse keys an identification would ignore: a test `duration` that disagrees with its data window.

    identify fits each test over its data window (Case.fit_window); `duration` then only sets
    the horizon of `crashnlp simulate`, so a different value would be silently ignored.
    """
    if problem.kind != "identify":
        return
    for i, test in enumerate(problem.tests):
        window = test.data.window if test.data is not None else None
        if test.duration is not None and window is not None and abs(test.duration - window[1]) > 1e-9:
            raise ProblemError(
                f"{source}: tests.{i}.duration: {test.duration:g} s would be ignored: identify fits the data "
                f"window, which ends at {window[1]:g} s (remove duration or make it {window[1]:g} s)"
            )


def load_problem(path: str | Path) -> Problem:
    """Load and validate a problem file."""
    path = Path(path)
    return problem_from_dict(read_yaml(path), path.resolve().parent, source=str(path))
