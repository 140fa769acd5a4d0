"""Studies: `crashnlp study` on the shipped pitch-bound study with 1 and with 2 workers.

Each run goes into a fresh temporary output folder (a study resumes from its
folder, so reusing one would time nothing). Skipped, with a note, when the
installed crashnlp has no `study` command yet.
"""

from __future__ import annotations

import csv
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.common import PROBLEMS, ROOT
from crashnlp.runtime import THREADS_ENV

CLI = Path(sys.executable).with_name("crashnlp")
STUDY = PROBLEMS / "studies" / "pitch-bound.yaml"
QUICK_STUDY = """\
name: pitch-bound-quick
problem: {problem}
sweep:
  constraints.bounds.pitch: [[null, 6 deg], [null, 10 deg]]
mode: grid
"""


def available() -> bool:
    """Whether `crashnlp study` exists."""
    return subprocess.run([str(CLI), "study", "--help"], capture_output=True, cwd=ROOT).returncode == 0


def run_once(study: Path, workers: int, serial_maps: bool = False) -> dict:
    """Wall time and outcome of one study run into a fresh folder.

    `serial_maps` sets CRASHNLP_THREADS=1, so that one worker uses one core and
    the comparison measures the executor rather than the threaded maps."""
    env = {**os.environ, THREADS_ENV: "1"} if serial_maps else None
    with tempfile.TemporaryDirectory(prefix="bench-study-") as out:
        cmd = [str(CLI), "study", str(study), "--workers", str(workers), "--out", out, "--no-progress"]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env=env)
        wall = time.perf_counter() - t0
        table = Path(out) / "table.csv"
        rows = list(csv.DictReader(table.open())) if table.exists() else []
    return {
        "workers": workers,
        "serial_maps": serial_maps,
        "wall_s": wall,
        "exit": proc.returncode,
        "cases": len(rows),
        "summary": (proc.stdout.strip().splitlines() or [proc.stderr.strip()[-300:]])[0],
        **plan_bound(rows),
    }


def plan_bound(rows: list[dict]) -> dict:
    """The solves' total time and the longest warm-start chain through them (IPOPT times).

    A case starts only after the case it warm-starts from, so no executor can finish the
    solves in less than the longest chain: total / max(chain, total / 2) bounds the
    speed-up of two workers whatever they cost to run."""
    if not rows:
        return {}
    wall = {r["case"]: float(r["wall_s"] or 0.0) for r in rows}
    parent = {r["case"]: r["warm_start"] or None for r in rows}
    chain = lambda c: wall[c] + (chain(parent[c]) if parent[c] else 0.0)
    total, longest = sum(wall.values()), max(chain(c) for c in wall)
    return {"solves_s": total, "longest_chain_s": longest, "two_worker_bound": total / max(longest, total / 2)}


def run(quick: bool = False) -> dict:
    """1 and 2 workers on the pitch-bound study (a 2-case version of it with --quick)."""
    if not available():
        note = "skipped: `crashnlp study` is not available in this installation yet"
        print(f"  {note}")
        return {"skipped": note}
    with tempfile.TemporaryDirectory(prefix="bench-study-spec-") as tmp:
        study = STUDY
        if quick:
            study = Path(tmp) / "quick.yaml"
            study.write_text(QUICK_STUDY.format(problem=PROBLEMS / "pickup-56kph.yaml"))
        runs = [run_once(study, w) for w in (1, 2)]
        serial = [run_once(study, w, serial_maps=True) for w in (1, 2)]
    for r in runs + serial:
        maps = "serial maps" if r["serial_maps"] else "default maps"
        print(f"  {r['workers']} worker(s), {maps}: {r['wall_s']:.1f} s, exit {r['exit']}, {r['cases']} cases: {r['summary']}")
    if "two_worker_bound" in serial[0]:
        s = serial[0]
        print(
            f"  solves {s['solves_s']:.2f} s, longest warm-start chain {s['longest_chain_s']:.2f} s: 2 workers at most {s['two_worker_bound']:.2f}x faster"
        )
    return {
        "study": STUDY.name if not quick else "pitch-bound (2 cases)",
        "runs": runs + serial,
        "speedup_2_workers": runs[0]["wall_s"] / runs[1]["wall_s"],
        "speedup_2_workers_serial_maps": serial[0]["wall_s"] / serial[1]["wall_s"],
    }
