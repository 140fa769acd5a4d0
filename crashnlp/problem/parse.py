"""YAML text to Python values: YAML's safe loader, refusing a key given twice and a flood of
aliases, its errors turned into one line that names the file (ProblemError)."""

from __future__ import annotations

from collections.abc import Hashable
from pathlib import Path
from typing import Any

import yaml

from crashnlp.problem.errors import ProblemError

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


def parse_yaml(text: str, path: Path) -> Any:
    """The values of the YAML `text` of the file `path`; a syntax error is a ProblemError."""
    try:
        return yaml.load(text, Loader=UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or ""
        why = ": a tab, where YAML indents and separates with spaces" if "'\\t'" in problem else f": {problem}" if problem else ""
        raise ProblemError(f"{path}:{where} not valid YAML{why}") from None
    except RecursionError:
        raise ProblemError(f"{path}: not valid YAML (nested too deeply)") from None
    except ValueError as exc:  # an integer of more digits than Python reads
        raise ProblemError(f"{path}: not valid YAML ({exc})") from None
