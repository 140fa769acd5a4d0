"""Copy the figures the README shows into results/readme/ (run after make demo, identify, study).

The crush-space figure is drawn here: best peak deceleration of the design study
against the crush space, beside the square-wave floor v0^2 / (2 C).
"""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from crashnlp.base.units import G0  # noqa: E402
from crashnlp.problem import load_problem  # noqa: E402

RESULTS = Path("results")
OUT = RESULTS / "readme"
COPIES = {
    "nhtsa-10146/10146/fit.png": "nhtsa-10146-fit.png",
    "pickup-joint/force_crush.png": "pickup-joint-force-crush.png",
    "pickup-56kph/56kph/fit.png": "pickup-56kph-fit.png",
}


def crush_space_figure(table: Path, problem: Path, path: Path) -> None:
    rows = list(csv.DictReader(table.open()))
    ok = [r for r in rows if r["status"] == "ok"]
    space = np.array([float(r["constraints.bounds.crush_si"]) for r in ok])
    test = load_problem(problem).tests[0].name
    peak = np.array([float(r[f"{test}.peak_decel_g"]) for r in ok])
    v0 = load_problem(problem).speed(load_problem(problem).tests[0])
    c = np.linspace(space.min(), space.max(), 100)
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    ax.plot(space * 1e3, peak, "o-", color="C0", label="best design (pendulum model, pitch <= 10 deg)")
    ax.plot(c * 1e3, v0**2 / (2 * c) / G0, "--", color="0.4", label="square wave v0^2 / (2 C)")
    ax.set_xlabel("crush space C (mm)")
    ax.set_ylabel("peak deceleration (g)")
    ax.set_title(f"pickup at {v0 * 3.6:.0f} km/h: best pulse against crush space")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    for src, dst in COPIES.items():
        if (RESULTS / src).exists():
            shutil.copyfile(RESULTS / src, OUT / dst)
    table = RESULTS / "crush-space/table.csv"
    if table.exists():
        crush_space_figure(table, Path("problems/design-crush-space.yaml"), OUT / "crush-space.png")
    print(f"wrote {OUT}/")


if __name__ == "__main__":
    main()
