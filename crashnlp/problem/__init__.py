"""Problem files: schema, loading and the parameter layout they define."""

from crashnlp.problem.load import ProblemError, load_problem, problem_from_dict
from crashnlp.problem.schema import Problem, Test

__all__ = ["Problem", "ProblemError", "Test", "load_problem", "problem_from_dict"]
