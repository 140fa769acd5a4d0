"""The functions IPOPT calls: built once per NLP shape, then loaded compiled.

IPOPT asks for five things at every iteration: f and g, the gradient of f, the
constraint Jacobian and the Hessian of the Lagrangian. crashnlp builds them as
CasADi Functions of (x, p) (crashnlp.numerics.derivatives for the structured Jacobian
and the Gauss-Newton Hessian) and, since every number that changes between runs
is in p (crashnlp.numerics.nlp), they depend on the problem's structure only. So they
are compiled to C once per structure and machine and kept in the crashnlp cache,
under a hash of the serialized NLP, the code that derives the compiled functions from it, the
Hessian kind and the compiler:

- `compile: auto` (default): a cached library when there is one; otherwise this
  solve runs in CasADi's virtual machine and the library is compiled in the
  background, for the later study cases of the same shape; when the command ends
  the compile finishes at nice 19 for the next run, with a line that says so
  (crashnlp.numerics.compile_job; CRASHNLP_KEEP_COMPILING=0 stops it with the command).
- `compile: now`: compile before solving and wait (before a large study).
- `compile: never`, or CRASHNLP_COMPILE=0 or =model: the virtual machine only.

A library is compiled once per machine at a time, under its lock (crashnlp.numerics.compiled:
a flock, released by the kernel when its compile dies): a process that finds its library being
compiled by another (a study's other worker, another command) does not compile it again. With
`auto` it solves in the virtual machine, as it would have without a compiler, rather than wait
(the compile takes several times a solve, and the next solve loads the library); with `now` it
waits for that compile, as for its own, and loads the library.

The exact Hessian (designs, and fits that Gauss-Newton cannot finish) is the
structured one of crashnlp.numerics.derivatives, compiled like the rest: derived by
nlpsol through the whole graph, its C code ran to tens of megabytes.

The virtual machine and the compiled code run the same operations in the same
order (no -ffast-math, no contraction into FMA), so both give the same bits:
a run does not change its result.json when its library appears.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from contextlib import suppress
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import casadi as ca

from crashnlp.base.cache import files_digest
from crashnlp.numerics import compiled, derivatives
from crashnlp.numerics.nlp import NLPBuilder
from crashnlp.problem.schema import Problem

NLP_FLAGS = ("-O1", "-ffp-contract=off", "-fPIC", "-shared")  # -O2 doubles gcc's time on 3 MB of C for ~10 % speed
COMPILE_ERRORS = (OSError, RuntimeError, subprocess.CalledProcessError)  # an unusable cache or compiler: stay in the VM
SOLVER_FUNCTIONS = ("nlp", "grad_f", "jac_g", "hess_lag")
SOLVER_OPTIONS = {"no_nlp_grad": True, "calc_lam_p": False, "calc_lam_x": False, "calc_f": False, "calc_g": False}
_loaded: dict[Path, dict[str, ca.Function]] = {}


@dataclass
class Oracle:
    """The NLP as nlpsol takes it: (x, p) -> (f, g), and its derivatives as options."""

    nlp: ca.Function | dict[str, ca.MX]
    derivatives: dict[str, ca.Function]
    key: str
    compiled: bool


def oracle(nlp: NLPBuilder, hessian: str, mode: str, expand: bool = False) -> Oracle:
    """The NLP's functions, compiled when `mode` and the machine allow (see the module); all of
    them, the NLP's extras too, are left in nlp.functions."""
    functions, built = _shape_functions(nlp, hessian, mode)
    if expand and not built:
        functions = {name: f.expand() for name, f in functions.items()}
    nlp.functions = functions
    solver = {name: f for name, f in functions.items() if name in SOLVER_FUNCTIONS}
    base = solver.pop("nlp")
    return Oracle(base if built else nlp.problem(), solver, f"{nlp.key()}-{hessian}", built)


def symbolic(problem: Problem) -> bool:
    """Whether a problem's NLP carries its numbers as parameters: where its solver section lets
    it be compiled, whether or not this machine compiles, so that the result is the same bits
    either way."""
    return problem.solver.compile != "never"


def compilable(problem: Problem) -> bool:
    """Whether a problem's NLP will be compiled here: symbolic, and a compiler is there."""
    return symbolic(problem) and compiled.compiler(nlp=True) is not None


def _shape_functions(nlp: NLPBuilder, hessian: str, mode: str) -> tuple[dict[str, ca.Function], bool]:
    """The solver's functions and the NLP's extras: from the library of this NLP shape when the
    cache holds one (True), else built (False) and compiled behind or now by `mode`. A cache
    that cannot be written or read, or a compiler that fails, leaves the VM's functions: the
    result is the same, only slower."""
    cc = compiled.compiler(nlp=True) if mode != "never" else None
    library = _library(nlp, "-".join([hessian, *sorted(nlp.extras)]), cc) if cc else None
    with suppress(*COMPILE_ERRORS):
        if library and (loaded := _load(library, _needed(nlp, hessian))) is not None:
            return loaded, True
    functions = {**_functions(nlp, hessian), **{name: make() for name, make in nlp.extras.items()}}
    if not (cc and library) or compiled.refused(library):
        return functions, False
    with suppress(*COMPILE_ERRORS):
        if mode != "now":
            _compile_behind(cc, functions, library)
            return functions, False
        with compiled.locked(library) as lock:
            if not library.exists():
                _write_names(functions, library)
                compiled.build(cc, _source(functions), library, lock, NLP_FLAGS)
        if (loaded := _load(library, _needed(nlp, hessian))) is not None:
            return loaded, True
    return functions, False


def _library(nlp: NLPBuilder, tag: str, cc: str) -> Path:
    """Where the library of this NLP shape, tag (Hessian and extras), compiler and flags lives."""
    key = hashlib.sha256("\0".join([nlp.key(), _code(_makers(nlp)), cc, *NLP_FLAGS]).encode()).hexdigest()[:20]
    return compiled.cache_dir() / f"nlp-{key}-{tag}.so"


def _makers(nlp: NLPBuilder) -> tuple[str, ...]:
    """The modules whose code turns the NLP's f and g into what is compiled: crashnlp.numerics.derivatives
    and crashnlp.numerics.nlp (the solver's functions), the module of each extra's maker (a function or a
    functools.partial of one), and this one."""
    extras = [getattr(make, "func", make).__module__ for _, make in sorted(nlp.extras.items())]
    return (derivatives.__name__, NLPBuilder.__module__, *extras, __name__)


@cache
def _code(modules: tuple[str, ...]) -> str:
    """A hash of the code of `modules` (all imported by then): a library from other code is not reused.

    The key of a library names the NLP (its serialized f and g) and this code, not the compiled
    functions themselves: serializing those would cost more than building them."""
    return files_digest(Path(str(sys.modules[m].__file__)) for m in modules)


def _write_names(functions: dict[str, ca.Function], library: Path) -> None:
    """The names of a library's Functions, beside it (written before the library appears)."""
    library.parent.mkdir(parents=True, exist_ok=True)
    library.with_suffix(".names").write_text("".join(f"{name}\n" for name in functions))


def _functions(nlp: NLPBuilder, hessian: str) -> dict[str, ca.Function]:
    """nlp, grad_f, jac_g and hess_lag (exact or Gauss-Newton; none for limited memory), as MX
    Functions of (x, p)."""
    problem = nlp.problem()
    x, p, f, g = (problem[k] for k in ("x", "p", "f", "g"))
    d = nlp.derivatives()
    out = {
        "nlp": nlp.function("nlp", [f, g], ["f", "g"]),
        "grad_f": nlp.function("grad_f", [f, ca.gradient(f, x)], ["f", "grad_f_x"]),
        "jac_g": d.jac_g(g),
    }
    if hessian == "gauss-newton":
        out["hess_lag"] = d.gauss_newton(nlp.residuals, nlp.rest, g.numel())
    elif hessian == "exact":
        out["hess_lag"] = d.hessian(f, g)
    return out


def _source(functions: dict[str, ca.Function]) -> str:
    gen = ca.CodeGenerator("nlp.c", {"with_header": False, "casadi_real": "double"})
    for fn in functions.values():
        gen.add(fn)
    return gen.dump()


def _load(library: Path, needed: set[str]) -> dict[str, ca.Function] | None:
    """Every Function of a library (once per process), or None where the cache holds no library
    that is whole and loads with the Functions `needed` (crashnlp.numerics.compiled.load_cached:
    one that is not is removed)."""
    if library not in _loaded:
        functions = compiled.load_cached(library, lambda: _externals(library, needed))
        if functions is None:
            return None
        _loaded[library] = functions
    return dict(_loaded[library])


def _externals(library: Path, needed: set[str]) -> dict[str, ca.Function]:
    """The Functions of `library`, by the names beside it (`_write_names`); a RuntimeError where
    they lack one `needed` (a list cut short, in a cache whose library has no record to vouch for it)."""
    names = library.with_suffix(".names").read_text().split()
    if missing := needed - set(names):
        raise RuntimeError(f"{library}: {', '.join(sorted(missing))} not in its list of functions")
    return {name: ca.external(name, str(library)) for name in names}


def _needed(nlp: NLPBuilder, hessian: str) -> set[str]:
    """The Functions a solver of `hessian` takes from an NLP's library (`_functions`' and the extras)."""
    return {"nlp", "grad_f", "jac_g", *(("hess_lag",) if hessian in ("gauss-newton", "exact") else ()), *nlp.extras}


def compiles_running(cache: Path) -> list[Path]:
    """The NLP libraries being compiled in `cache` now: those whose lock a compile holds
    (crashnlp.numerics.compiled.compiling)."""
    libraries = (lock.with_suffix(".so") for lock in cache.glob("nlp-*.lock"))
    return [library for library in libraries if compiled.compiling(library)]


def _compile_behind(cc: str, functions: dict[str, ca.Function], library: Path) -> None:
    """Start compiling the library beside this process (crashnlp.numerics.compile_job: stopped with an
    interrupted command, finished at nice 19 after one that ends), holding its lock: none if another
    compile holds it, or wrote the library meanwhile. No more compiles at once than cores: a batch
    of many shapes compiles the rest on later runs."""
    if len(compiles_running(library.parent)) >= (os.cpu_count() or 1):
        return

    def source() -> str:
        _write_names(functions, library)
        return _source(functions)

    compiled.start_behind(cc, library, NLP_FLAGS, source)
