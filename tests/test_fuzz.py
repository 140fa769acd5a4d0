"""Fuzz: seeded random mutations of every shipped problem and study, of their data and of the options.

Every run must end with exit status 0, 1 or 2, print no traceback, and an exit 2 must leave nothing
behind (no output folder). Runs go through `crashnlp.cli.main(argv)` in this process, the same
function the console script calls. Most runs add `--check` (everything but the solve); the others
get a tiny iteration budget so that a mutation that passes validation stops early.

CRASHNLP_FUZZ_SECONDS (default 15: `make test`'s share) bounds the time, CRASHNLP_FUZZ_RUNS (default unbounded within
the time) the number of runs, CRASHNLP_FUZZ_SEED (default 14) the seed; `make fuzz` runs 2000.
A failure names the run and its mutation; rerun with the same seed to reproduce it.
"""

from __future__ import annotations

import contextlib
import copy
import io
import json
import math
import os
import random
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
import yaml
from builders import ROOT

from crashnlp.cli import main

pytestmark = [pytest.mark.integration, pytest.mark.slow]

PROBLEMS = sorted((ROOT / "problems").glob("*.yaml"))
STUDIES = sorted((ROOT / "problems/studies").glob("*.yaml"))
SECONDS = float(os.environ.get("CRASHNLP_FUZZ_SECONDS", "15"))
RUNS = int(os.environ.get("CRASHNLP_FUZZ_RUNS", "0")) or None
SEED = int(os.environ.get("CRASHNLP_FUZZ_SEED", "14"))
FULL_RUNS = 0.12  # share of problem runs that solve (with a tiny budget) instead of --check

HOSTILE: list[Any] = [
    math.nan,
    math.inf,
    -math.inf,
    1e308,
    -1e308,
    10**30,
    -1,
    0,
    1e-300,
    -1e-9,
    "",
    " ",
    "abc",
    "56",
    "-5 km/h",
    "56 kg",
    "nan m",
    "inf s",
    "1e308 MN",
    "1e-400 m",
    "3 furlong",
    "12 %",
    "0x10",
    [],
    {},
    None,
    True,
    False,
    [None],
    [math.nan],
    {"x": 1},
    list(range(200)),
    "\x00",
    "é",
    "../../etc/passwd",
    "data",
    2**63,
    -(2**63),
]
UNITS = ["m", "mm", "s", "ms", "kg", "g", "km/h", "m/s", "deg", "rad", "N", "kN", "MN/m", "N*s/m", "furlong", "%", ""]
KEYWORDS = [
    "csv",
    "nhtsa-ev5",
    "iso-mme",
    "force",
    "secant",
    "plastic",
    "elastic",
    "l1",
    "l2",
    "collocation",
    "multiple-shooting",
    "design",
    "identify",
    "radau",
    "legendre",
    "CFC60",
    "CFC9",
    "integrate",
    "zip",
    "grid",
]


@dataclass
class Run:
    """One fuzz run: the files it wrote, the command line, and what was done (for the failure message)."""

    folder: Path
    argv: list[str]
    steps: list[str] = field(default_factory=list)
    out: Path | None = None


# --------------------------------------------------------------------------- tree mutations
def _paths(node: Any, prefix: tuple = ()) -> list[tuple]:
    out = [prefix]
    if isinstance(node, dict):
        for k, v in node.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += _paths(v, prefix + (i,))
    return out


def _get(node: Any, path: tuple) -> Any:
    for k in path:
        node = node[k]
    return node


def _scaled(value: Any, rng: random.Random) -> Any:
    factor = rng.choice([1e-3, 1e3, -1, 3.6, 1 / 3.6, 0, 1e12])
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return value
    return value * factor


def _reunit(value: Any, rng: random.Random) -> Any:
    if isinstance(value, str) and " " in value:
        number, _ = value.split(" ", 1)
        return f"{number} {rng.choice(UNITS)}".strip()
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return f"{value} {rng.choice(UNITS)}".strip()
    return value


def mutate_tree(raw: Any, rng: random.Random, steps: list[str]) -> Any:
    """One random change of a parsed YAML tree: a value, a unit, a type, a key."""
    raw = copy.deepcopy(raw)
    path = rng.choice(_paths(raw))
    kind = rng.choice(["value", "value", "scale", "unit", "type", "delete", "add", "rename", "keyword"])
    steps.append(f"{kind} at {'.'.join(map(str, path)) or '<root>'}")
    if not path:
        return rng.choice(HOSTILE) if kind == "value" else raw
    parent, key = _get(raw, path[:-1]), path[-1]
    value = parent[key]
    if kind == "value":
        parent[key] = copy.deepcopy(rng.choice(HOSTILE))
    elif kind == "scale":
        parent[key] = _scaled(value, rng)
    elif kind == "unit":
        parent[key] = _reunit(value, rng)
    elif kind == "type":
        parent[key] = [value] if not isinstance(value, list) else (value[0] if value else {})
        if isinstance(value, (int, float)) and not isinstance(value, bool) and rng.random() < 0.5:
            parent[key] = str(value)
    elif kind == "delete":
        del parent[key]
    elif kind == "add" and isinstance(parent, dict):
        parent[rng.choice(["colour", "mass", "speed", "file", "window", "unit", str(key) + "s"])] = rng.choice(HOSTILE)
    elif kind == "rename" and isinstance(parent, dict) and isinstance(key, str) and len(key) > 1:
        parent[key[:-1]] = parent.pop(key)
    elif kind == "keyword":
        parent[key] = rng.choice(KEYWORDS)
    return raw


# --------------------------------------------------------------------------- text mutations
def mutate_text(data: bytes, rng: random.Random, steps: list[str]) -> bytes:
    """One random change of a file's bytes: truncation, garbage, a line twice or gone, an encoding."""
    kind = rng.choice(["truncate", "bytes", "duplicate", "drop", "char", "encoding", "empty"])
    steps.append(f"text {kind}")
    lines = data.splitlines(keepends=True)
    at = rng.randrange(len(data) + 1)
    if kind == "truncate":
        return data[:at]
    if kind == "bytes":
        return data[:at] + bytes(rng.randrange(256) for _ in range(rng.randint(1, 8))) + data[at:]
    if kind == "duplicate" and lines:
        i = rng.randrange(len(lines))
        return b"".join(lines[: i + 1] + [lines[i]] + lines[i + 1 :])
    if kind == "drop" and lines:
        i = rng.randrange(len(lines))
        return b"".join(lines[:i] + lines[i + 1 :])
    if kind == "char" and data:
        return data[:at] + rng.choice(list(b":[]{}-&*!|>'\"%@`#,\t\n")).to_bytes(1, "big") + data[at + 1 :]
    if kind == "encoding":
        text = data.decode("utf-8", errors="replace") + "# café\n"
        return text.encode(rng.choice(["utf-16", "latin-1", "utf-32", "cp1252"]), errors="replace")
    return b"" if kind == "empty" else data


# --------------------------------------------------------------------------- one run
def _copy_problems(folder: Path) -> Path:
    """problems/ as files of this run: the YAML files copied, the data linked (mutated data are copies)."""
    problems = folder / "problems"
    (problems / "studies").mkdir(parents=True)
    for p in PROBLEMS:
        shutil.copy(p, problems / p.name)
    for p in STUDIES:
        shutil.copy(p, problems / "studies" / p.name)
    (problems / "data").symlink_to(ROOT / "problems/data")
    return problems


def _mutate_data(problems: Path, raw: dict, rng: random.Random, steps: list[str]) -> None:
    """Point a test of the problem at a mutated copy of its data (CSV, or an EV5 header beside the curves)."""
    tests = raw.get("tests") if isinstance(raw, dict) else None
    if not isinstance(tests, list) or not tests or not isinstance(tests[0], dict):
        return
    data = tests[0].get("data")
    if not isinstance(data, dict) or not isinstance(data.get("file"), str):
        return
    source = problems / data["file"]
    if not source.is_file():
        return
    copy_dir = problems / "mutated-data"
    copy_dir.mkdir(exist_ok=True)
    if source.suffix.upper() == ".EV5":
        for curve in source.parent.glob(source.stem + ".*"):
            link = copy_dir / curve.name
            if curve != source and not link.exists() and not link.is_symlink():
                link.symlink_to(curve)
    target = copy_dir / source.name
    steps.append(f"data {source.name}:")
    target.write_bytes(mutate_text(source.read_bytes(), rng, steps))
    data["file"] = f"mutated-data/{source.name}"


def _options(rng: random.Random, command: str, folder: Path, steps: list[str]) -> tuple[list[str], Path]:
    """Random command-line options of a command, and the output folder the run may create."""
    out = folder / "out"
    opts: list[str] = []
    choice = rng.random()
    if choice < 0.08:
        blocker = folder / "blocker"
        blocker.write_text("")
        out = rng.choice([blocker, blocker / "sub"])
    elif choice < 0.12:
        out = Path(rng.choice(["/proc/crashnlp-out", "/dev/null/out"]))
    if rng.random() < 0.1:  # the default folder, results/ under the working directory
        out = Path.cwd() / "results"
    else:
        opts += ["--out", str(out)]
    extra = rng.random()
    if command == "simulate" and extra < 0.3:
        opts += ["--dt", rng.choice(["0", "-1", "nan", "inf", "1e-9", "abc", "1e-3", "1e300", "-0"])]
    if command == "simulate" and rng.random() < 0.15:
        params = folder / "result.json"
        params.write_text(
            rng.choice(
                [
                    "{",
                    "[]",
                    '{"parameters": 3}',
                    '{"parameters": {"model.spring.values": [1, 2]}}',
                    '{"parameters": {"vehicle.mass": "x"}}',
                    '{"parameters": {"vehicle.mass": null}}',
                    '{"parameters": {"vehicle.colour": 1}}',
                    '{"parameters": {"vehicle.mass": 1e308}}',
                ]
            )
        )
        opts += ["--params", rng.choice([str(params), str(folder / "none.json"), str(folder)])]
    if command == "study":
        if rng.random() < 0.3:
            opts += ["--workers", rng.choice(["0", "-3", "abc", "1", "2"])]
        if rng.random() < 0.3:
            opts += ["--executor", rng.choice(["local", "dask", "bogus"])]
        if rng.random() < 0.2:
            opts += ["--address", rng.choice(["foo", "", "tcp://[::1", "tcp://127.0.0.1:1"])]
            if opts[-1] == "tcp://127.0.0.1:1":
                opts += ["--timeout", "0.2"]  # unreachable: fails (exit 1) within the timeout
        if rng.random() < 0.2:
            opts += ["--timeout", rng.choice(["0", "-1", "nan", "5", "1e9"])]
        opts += ["--no-progress"]
    if rng.random() < 0.05:
        opts += [rng.choice(["--bogus", "--verbose", "--dt", "-x", "--out"])]
    if opts:
        steps.append("options " + " ".join(opts))
    return opts, out


def make_run(i: int, base: Path) -> Run:
    """The files and command line of run i (seeded by SEED and i alone)."""
    rng = random.Random(f"{SEED}-{i}")
    folder = base / f"run-{i:05d}"
    problems = _copy_problems(folder)
    study = rng.random() < 0.25
    target = problems / "studies" / rng.choice(STUDIES).name if study else problems / rng.choice(PROBLEMS).name
    steps: list[str] = [f"{target.relative_to(folder)}"]
    raw = yaml.safe_load(target.read_text())
    full = not study and rng.random() < FULL_RUNS
    if not full and rng.random() < 0.3:
        target.write_bytes(mutate_text(target.read_bytes(), rng, steps))
    else:
        for _ in range(rng.choice([1, 1, 1, 2, 3])):
            if rng.random() < 0.15 and not study:
                _mutate_data(problems, raw, rng, steps)
            else:
                raw = mutate_tree(raw, rng, steps)
        if full and isinstance(raw, dict):  # a tiny budget: a mutation that passes validation stops early
            raw["solver"] = {"ipopt": {"max_iter": 2}}
            raw["transcription"] = {"method": "multiple-shooting", "intervals": 20}
            steps.append("full run, max_iter 2, 20 intervals")
        target.write_text(yaml.safe_dump(raw, allow_unicode=rng.random() < 0.5))
    if study and rng.random() < 0.3:  # the study's base problem too
        base = problems / rng.choice(PROBLEMS).name
        steps.append(f"base {base.name}:")
        base.write_text(yaml.safe_dump(mutate_tree(yaml.safe_load(base.read_text()), rng, steps)))
    if study:
        command = "study"
    else:
        kind = raw.get("kind", "identify") if isinstance(raw, dict) else "identify"
        command = rng.choice(["simulate", kind if kind in ("identify", "design") else "identify", "design"])
    opts, out = _options(rng, command, folder, steps)
    argv = [command, str(target), *opts] if rng.random() > 0.02 else [command, *opts]
    if not full:
        argv.append("--check")
    return Run(folder, argv, steps, out)


def check(run: Run, i: int) -> int:
    """Run the command in this process and hold it to the rules of issue 14."""
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = main(list(run.argv))
    err = stderr.getvalue()
    where = f"run {i} (seed {SEED}): {' / '.join(run.steps)}\n  crashnlp {' '.join(run.argv)}\n  exit {code}: {err[-2000:]}"
    assert code in (0, 1, 2), where
    assert "Traceback" not in err, where
    if code == 2:
        assert err.count("\n") == 1 and err.startswith("crashnlp: error: "), where
        assert run.out is None or not run.out.exists() or run.out.is_file() or not any(run.out.iterdir()), where
        assert not (run.folder / "results").exists(), where
    if code == 1:
        assert err.strip().splitlines()[-1].startswith("crashnlp: "), where
        # with --check nothing is solved: exit 1 is only an unreachable cluster, never a crash of our own
        assert "--check" not in run.argv or "--address" in run.argv, where
    if "--check" in run.argv and run.out is not None and run.out.is_dir():
        assert not any(run.out.iterdir()), where + "\n  --check wrote files"
    return code


def test_fuzz_every_shipped_problem_study_and_option(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the default output folder results/ lands here
    monkeypatch.setenv("CRASHNLP_THREADS", "1")
    started, i, codes = time.monotonic(), 0, {}
    while time.monotonic() - started < SECONDS and (RUNS is None or i < RUNS):
        run = make_run(i, tmp_path)
        code = check(run, i)
        kind = f"{code}{'' if '--check' in run.argv else ' full'}"
        codes[kind] = codes.get(kind, 0) + 1
        shutil.rmtree(run.folder, ignore_errors=True)
        shutil.rmtree(tmp_path / "results", ignore_errors=True)
        i += 1
    assert i >= min(RUNS or 50, 50), f"only {i} runs in {SECONDS} s"
    print(f"{i} fuzz runs in {time.monotonic() - started:.1f} s (seed {SEED}), exit statuses {sorted(codes.items())}")


def test_fuzz_is_reproducible(tmp_path):
    a, b = make_run(7, tmp_path / "a"), make_run(7, tmp_path / "b")
    assert [x.replace("/a/", "/b/") for x in a.steps] == b.steps
    assert [x.replace("/a/", "/b/") for x in a.argv] == b.argv
    assert json.dumps(sorted(p.name for p in a.folder.rglob("*"))) == json.dumps(sorted(p.name for p in b.folder.rglob("*")))
