"""crashnlp from Python: identify the synthetic pickup, look at the result, simulate a
faster impact with the identified vehicle, and run a what-if study.

Run from the repository root: `python examples/quickstart.py` (the test suite runs it).
"""

import crashnlp


def main() -> None:
    problem = crashnlp.load("problems/pickup-56kph.yaml")  # validated, immutable
    result = crashnlp.identify(problem)  # also crashnlp.design(problem)

    print(result.status, result.solver.iterations, "iterations")
    print("spring values (N):", result.parameters["model.spring.values"])
    print("their std (N):    ", result.std_errors["model.spring.values"])
    print("max displacement (m):", result.tests["56kph"].metrics["max_displacement_m"])  # the CG's travel
    print("energy balance error:", result.tests["56kph"].energy["balance_error_relative"])
    result.save("results/pickup-56kph")  # the files `crashnlp identify` writes

    faster = problem.with_values({"vehicle.speed": "64 km/h"})  # a new problem; `problem` is unchanged
    test = crashnlp.simulate(faster, params=result)["56kph"]  # the identified vehicle, with 95 % intervals
    # name -> array, per test; the CG's travel is "displacement", the front end's shortening "crush"
    print("max displacement at 64 km/h (m):", test["displacement_m"].max(), test.intervals["max_displacement_m"])
    print("max front-end crush at 64 km/h (m):", test["crush_m"].max(), test.metrics["max_front_end_crush_m"])
    print("past the fitted range:", test.extrapolation)

    table = crashnlp.study("problems/studies/pitch-bound.yaml", executor="local")
    for row in table:
        print(row["case"], row["status"], row.get("objective"))


if __name__ == "__main__":  # studies start worker processes, which import this file
    main()
