"""Problem files: schema, loading and the parameter layout they define."""

from crashnlp.problem.errors import ProblemError
from crashnlp.problem.load import load_problem
from crashnlp.problem.schema import Problem, Test, problem_from_dict

__all__ = ["Problem", "ProblemError", "Test", "load_problem", "problem_from_dict"]
