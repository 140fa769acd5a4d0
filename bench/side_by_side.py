"""The whole_process section's commands, this checkout against an earlier commit, in one run:
`python bench/side_by_side.py [REF] [--repeats N] [--new M]` (REF: main by default).

A change that shaves milliseconds off a command is measured against the code before it on the
same machine in the same minutes, not against last week's report: REF's `crashnlp` package is
exported to a temporary folder and each command runs as a process under either package
(PYTHONPATH; the same interpreter, numpy and CasADi), the two taking turns, each run followed by
the floor (bench/whole_process.py, one OpenBLAS thread). Measured, per version: a new problem
written by `crashnlp init` identified three times from an empty cache of its own (run 3 once the
library compiled after run 1 is ready), then the warm pickup with and without figures
(medians of N turns), wall and CPU time and their ratios to the floor's median; the new
problem's runs are medians of --new such sequences.
"""

from __future__ import annotations

import argparse
import compileall
import os
import statistics
import subprocess
import sys
import tarfile
import tempfile
from io import BytesIO
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import PICKUP_56, ROOT, wait_for_compiles  # noqa: E402
from bench.whole_process import CAMRY_EV5, CLI, FLOOR_KEY, as_a_user, taking_turns  # noqa: E402

VERSIONS = ("before", "after")


def export(ref: str, folder: Path) -> Path:
    """REF's crashnlp package, written under `folder` with its bytecode (as an install has it)."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", ref, "crashnlp"], check=True, capture_output=True).stdout
    with tarfile.open(fileobj=BytesIO(archive)) as tar:
        tar.extractall(folder, filter="data")
    compileall.compile_dir(folder / "crashnlp", quiet=1)
    return folder


def runs(commands: dict[str, list[str]], envs: dict[str, dict[str, str]], repeats: int) -> dict[str, dict]:
    """Each command under each version, in turns, each run followed by the floor: name/version -> times."""
    turns = {f"{name}/{v}": (command, envs[v]) for name, command in commands.items() for v in VERSIONS}
    return taking_turns(turns, repeats, floors=1)


def new_problem(folder: Path, envs: dict[str, dict[str, str]], repeats: int) -> dict[str, dict]:
    """Runs 1, 2 and 3 of a problem written by `crashnlp init`, `repeats` times, each version with an
    empty cache of its own each time: name/version -> the runs' wall and CPU times."""
    problem = folder / "camry.yaml"
    subprocess.run([CLI, "init", str(CAMRY_EV5), "--out", str(problem)], check=True, capture_output=True)
    identify = [CLI, "identify", str(problem), "--no-figures", "--out", str(folder / "camry")]
    out: dict[str, dict] = {}
    for r in range(repeats):
        own = {v: {**env, **as_a_user(folder / f"cache-{v}-{r}")} for v, env in envs.items()}
        turns = {n: runs({f"new_run_{n}": identify}, own, 1) for n in (1, 2)}
        for v in VERSIONS:
            wait_for_compiles(folder / f"cache-{v}-{r}")
        turns[3] = runs({"new_run_3": identify}, own, 1)
        for n, turn in turns.items():
            for key, t in turn.items():
                slot = out.setdefault(f"new_run_{n}/{FLOOR_KEY}" if key == FLOOR_KEY else key, {"walls_s": [], "cpus_s": []})
                slot["walls_s"] += t["walls_s"]
                slot["cpus_s"] += t["cpus_s"]
    return {
        key: {**r, "wall_s": statistics.median(r["walls_s"]), "cpu_s": statistics.median(r["cpus_s"])} for key, r in out.items()
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("ref", nargs="?", default="main")
    ap.add_argument("--repeats", type=int, default=7, help="turns of the warm pickup")
    ap.add_argument("--new", type=int, default=3, help="new problems, each from an empty cache")
    args = ap.parse_args(argv)
    compileall.compile_dir(ROOT / "crashnlp", quiet=1)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        base = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
        paths = {"before": export(args.ref, folder / "before"), "after": ROOT}
        envs = {v: {**base, "PYTHONPATH": str(paths[v])} for v in VERSIONS}
        out = new_problem(folder, envs, args.new)
        warm = {v: {**env, **as_a_user(folder / f"pickup-{v}")} for v, env in envs.items()}
        identify = [CLI, "identify", str(PICKUP_56), "--out", str(folder / "out")]
        runs({"prime": [*identify, "--no-figures"]}, warm, 1)
        for v in VERSIONS:
            wait_for_compiles(folder / f"pickup-{v}")
        out |= runs({"pickup_no_figures": [*identify, "--no-figures"], "pickup_figures": identify}, warm, args.repeats)
    floors = [w for key, r in out.items() if key.endswith(FLOOR_KEY) for w in zip(r["walls_s"], r["cpus_s"], strict=True)]
    floor_wall, floor_cpu = (statistics.median(x) for x in zip(*floors, strict=True))
    print(f"floor (median of {len(floors)}): {floor_wall:.3f} s wall, {floor_cpu:.3f} s CPU")
    print("| command | before: wall, CPU (s) | after: wall, CPU (s) | before: x floor (wall, CPU) | after: x floor (wall, CPU) |")
    print("|---|---|---|---|---|")
    for name in ("new_run_1", "new_run_2", "new_run_3", "pickup_no_figures", "pickup_figures"):
        r = {v: out[f"{name}/{v}"] for v in VERSIONS}
        cells = [f"{r[v]['wall_s']:.2f}, {r[v]['cpu_s']:.2f}" for v in VERSIONS]
        ratios = [f"{r[v]['wall_s'] / floor_wall:.1f}, {r[v]['cpu_s'] / floor_cpu:.1f}" for v in VERSIONS]
        print(f"| {name} | {' | '.join(cells)} | {' | '.join(ratios)} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
