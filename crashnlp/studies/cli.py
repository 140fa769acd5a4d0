"""The `crashnlp study` subcommand."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from crashnlp.base.choices import EXECUTORS
from crashnlp.engine import CONNECT_TIMEOUT

DESCRIPTION = """\
Solve a base problem again for every combination (grid) or every position (zip)
of the values given under `sweep`, each value replacing the entry at its dotted
path in the problem file. A study file:

  name: pitch-bound
  problem: ../pickup-56kph.yaml           # relative to the study file
  sweep:
    constraints.bounds.pitch: [[null, 4 deg], [null, 6 deg], [null, 8 deg]]
  mode: grid                              # grid | zip
  seeds: [0, 2]                           # optional: cases solved cold
  # max_depth: 3                          # or: seeds on a lattice, no case more than 3 warm starts from one

Seed cases (default: the corners of the grid) are solved cold; every other case
warm-starts from a neighbour one step closer to the nearest seed, and starts as
soon as that neighbour is solved. The plan depends only on the case list, so
every executor and worker count gives the same table.

Writes OUT/table.csv (one row per case: swept values as written and in SI,
status, IPOPT's return status, objective, iterations, solve time, metrics, the CFC class each
test's accelerations were read through (<test>.accel_filter), estimated parameters,
multipliers of the swept constraints = d objective / d bound), OUT/figures/, and
OUT/cases/ (each case as it finishes). Running again into the same OUT resumes:
a finished case (also a failed one) is not solved again while its problem, the
contents of its data files and crashnlp are unchanged; the run says how many it reused.

Exit status: 0 all cases ok, 1 some case failed, 2 bad input.
"""


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register `study` on the crashnlp command's subparsers."""
    p = subparsers.add_parser(
        "study",
        help="solve a problem for every value of swept entries (constraint what-if studies)",
        description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("study", help="study YAML file")
    p.add_argument("--out", help="output folder (default results/<study name>)")
    p.add_argument(
        "--executor",
        choices=EXECUTORS,
        default="local",
        help="local: a process pool on this machine (default); dask: a dask.distributed cluster (pip install 'crashnlp[dask]')",
    )
    p.add_argument("--workers", type=int, help="worker processes (default: the cores available; ignored with --address)")
    p.add_argument("--address", help="scheduler of a running dask cluster, e.g. tcp://host:8786 (default: start a local one)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument(
        "--timeout",
        type=float,
        default=CONNECT_TIMEOUT,
        help=f"seconds a dask scheduler at --address may take to answer (default {CONNECT_TIMEOUT:g})",
    )
    p.set_defaults(func=cmd_study)
    return p


def cmd_study(args) -> int:
    """Run the study; print where the table is and which cases failed."""
    from crashnlp.base.errors import InputError, Interrupted
    from crashnlp.engine.executors import require_dask, start_early
    from crashnlp.results.files import check_output, run_name

    check = getattr(args, "check", False)
    if args.executor == "dask":
        require_dask()
    elif not check:
        start_early()
    from crashnlp.studies.run import RESULTS, checked_workers, run_study
    from crashnlp.studies.spec import load_study
    from crashnlp.studies.store import CaseStore

    checked_workers(args.workers, "--workers")
    if not (math.isfinite(args.timeout) and 0 < args.timeout <= 3600):
        raise InputError(f"--timeout {args.timeout:g}: must be a number of seconds from 0 to 3600")
    if args.address is not None and args.executor != "dask":
        raise InputError("--address needs --executor dask")
    name = load_study(args.study).name
    out = check_output(Path(args.out) if args.out else RESULTS / name, run_name("study", name))
    try:
        rows = run_study(
            args.study,
            out,
            args.executor,
            args.workers,
            args.address,
            progress=not args.no_progress,
            timeout=args.timeout,
            check=check,
            tell=print,
        )
    except Interrupted as exc:
        cases = CaseStore(out / "cases")
        kept = f"; finished cases are kept in {cases.folder}/: run the study again to resume"
        exc.detail = kept if cases.holds_any() else "; no case had finished"
        raise
    if check:
        if args.executor == "dask" and args.address is not None:  # reachable within --timeout?
            from crashnlp.engine.executors import make_executor

            make_executor("dask", None, args.address, args.timeout).close()
        print(f"{args.study}: ok (would write {out}/)")
        return 0
    failed = [r for r in rows if r["status"] != "ok"]
    print(f"{len(rows) - len(failed)} of {len(rows)} cases ok; wrote {out}/table.csv and {out}/figures/")
    for r in failed:
        solver = f" (IPOPT {r['return_status']})" if r.get("return_status") else ""
        print(f"  {r['case']}: {r['status']}{solver}")
    if failed:  # exit status 1 and its one line on stderr, as a fit's solve that is not ok
        named = ", ".join(r["case"] for r in failed)
        print(f"crashnlp: {name}: {len(failed)} of {len(rows)} cases failed ({named}; {out}/table.csv says why)", file=sys.stderr)
    return 1 if failed else 0
