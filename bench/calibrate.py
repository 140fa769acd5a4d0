"""`make calibrate`: every model form's table of the intervals' form term from its held-out records.

`python bench/calibrate.py` fits the corpus of bench/calibration.py from scratch (or, with
--cache DIR, reads the records a former run left there) and writes each model form's table into
crashnlp/analysis/calibration.json, the check seed's and the hidden population's records into
tests/data/calibration-held-out.json.gz, and the intervals section of results/bench.*;
`--forms FORM ...` makes the named forms' tables only, every other form's as it was.
"""

from __future__ import annotations

import argparse
import gzip
import json
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import report  # noqa: E402
from bench.calibration import (  # noqa: E402
    CHECK_RECORDS,
    CHECK_SEED,
    HIDDEN_SEED,
    MODEL_FORMS,
    compact,
    held_out_records,
    merged,
    records,
    section,
)
from bench.common import RESULTS, ROOT  # noqa: E402
from crashnlp.analysis.calibration import FILE  # noqa: E402
from crashnlp.numerics.compiled import SWITCH_ENV as COMPILE_ENV  # noqa: E402
from crashnlp.problem.forms import DEFAULT_FORM  # noqa: E402

BENCH_JSON, BENCH_MD = RESULTS / "bench.json", RESULTS / "bench.md"


def write(by_form: dict[str, dict[int, list[dict]]]) -> None:
    """The model forms of `by_form`: each one's table into crashnlp/analysis/calibration.json, its
    check seed's and hidden population's records into CHECK_RECORDS (compact), its part of the
    section into results/bench.*; every other form's as it was there."""
    made = {form: {**section(rows, form), "shipped": True} for form, rows in by_form.items()}
    path = ROOT / "crashnlp" / "analysis" / FILE
    tables = json.loads(path.read_text()) if path.exists() else {}
    path.write_text(json.dumps(tables | {form: s["calibration"] for form, s in made.items()}, indent=1) + "\n")
    held = held_out_records() if CHECK_RECORDS.exists() else {}
    held |= {form: {str(seed): compact(rows[seed]) for seed in (CHECK_SEED, HIDDEN_SEED)} for form, rows in by_form.items()}
    CHECK_RECORDS.write_bytes(gzip.compress(json.dumps(held, separators=(",", ":")).encode(), mtime=0))
    results = json.loads(BENCH_JSON.read_text()) if BENCH_JSON.exists() else {}
    results["intervals"] = merged(results.get("intervals", {}), made)
    report.write(results, BENCH_JSON, BENCH_MD)
    print(f"wrote {path}, {CHECK_RECORDS}, {BENCH_JSON} and {BENCH_MD}")


def main(argv: list[str] | None = None) -> int:
    """`make calibrate`: every model form's table (or those --forms names) from scratch, or with
    --cache DIR from the records a former run left there."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cache", type=Path, help="a folder that keeps each vehicle's records between runs")
    parser.add_argument(
        "--forms", nargs="+", choices=list(MODEL_FORMS), default=list(MODEL_FORMS), help="the model forms to calibrate"
    )
    args = parser.parse_args(argv)
    if DEFAULT_FORM not in args.forms and "intervals" not in (json.loads(BENCH_JSON.read_text()) if BENCH_JSON.exists() else {}):
        parser.error(f"{BENCH_JSON}: no key intervals to add the forms to; calibrate {DEFAULT_FORM} too")
    if args.cache is not None:
        args.cache.mkdir(parents=True, exist_ok=True)
    os.environ.setdefault(COMPILE_ENV, "model")  # each corpus fit's NLP has a shape of its own: a compile outlasts it
    write({form: records(form, cache=args.cache) for form in dict.fromkeys(args.forms)})
    return 0


if __name__ == "__main__":
    sys.exit(main())
