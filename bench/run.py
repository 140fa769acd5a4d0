"""Run the crashnlp benchmarks: `python bench/run.py [--only SECTION] [--quick]`.

Sections run one after another (never two heavy ones at once). Results go to
results/bench.json and results/bench.md (results/bench-quick.* with --quick);
with --only, the other sections' earlier results in the JSON are kept.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import (  # noqa: E402
    calibration,
    choice,
    convergence,
    cross_speed,
    detectors,
    forms,
    identification,
    report,
    robustness,
    scaling,
    self_consistency,
    simulation,
    studies,
    truncated,
    whole_process,
)
from bench.common import RESULTS, machine, wait_for_compiles  # noqa: E402
from crashnlp.base.cache import cache_dir  # noqa: E402

SECTIONS = {
    "identification": identification,
    "simulation": simulation,
    "studies": studies,
    "scaling": scaling,
    "corpus": robustness,
    "self_consistency": self_consistency,
    "cross_speed": cross_speed,
    "forms": forms,  # every model form on the tall vehicles: docs/model.md's "Which form when"
    "choice": choice,  # compare's choice from one test against each form's prediction of the other speeds
    "intervals": calibration,  # the form term's table set on one seed, checked on another; make calibrate ships it
    "whole_process": whole_process,
    "detectors": detectors,  # the watch's rules: set on one corpus seed, checked on another
    "truncated": truncated,  # records cut short: MID_CRASH checked on a seed it was not set on
    "convergence": convergence,  # reads the corpus, scaling and studies sections' fits: bench/report.py
}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=SECTIONS, help="run one section")
    ap.add_argument("--quick", action="store_true", help="short smoke run with smaller sizes")
    args = ap.parse_args(argv)
    stem = "bench-quick" if args.quick else "bench"
    json_path, md_path = RESULTS / f"{stem}.json", RESULTS / f"{stem}.md"
    results = json.loads(json_path.read_text()) if args.only and json_path.exists() else {}
    results.update(machine=machine(), quick=args.quick)
    for name, module in SECTIONS.items():
        if args.only and name != args.only:
            continue
        print(f"[{name}]", flush=True)
        # an earlier section's background compiles (exact-Hessian libraries take minutes) would
        # share the cores with this one's timings: the whole process took 1.41 s beside them, 0.97 s alone
        waited = wait_for_compiles(cache_dir(), timeout=1200.0)
        if waited > 1:
            print(f"[{name}] waited {waited:.0f} s for background compiles to finish", flush=True)
        t0 = time.perf_counter()
        results[name] = module.run(quick=args.quick)
        print(f"[{name}] {time.perf_counter() - t0:.0f} s", flush=True)
    report.write(results, json_path, md_path)
    print(f"wrote {json_path} and {md_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
