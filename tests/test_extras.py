"""Optional extras: `pip install crashnlp` brings no dask; asking for dask without it is one line
that says what to install (exit 2), before any case is checked or solved."""

from __future__ import annotations

import sys
import tomllib

import pytest
import yaml
from builders import ROOT

from crashnlp.base.errors import InputError
from crashnlp.cli import main
from crashnlp.engine import DASK_EXTRA
from crashnlp.optimize.pipeline import prepare_case
from crashnlp.problem import problem_from_dict

STUDY = ROOT / "problems/studies/pitch-bound.yaml"
PICKUP = ROOT / "problems/pickup-56kph.yaml"


@pytest.fixture
def no_dask(monkeypatch):
    """dask.distributed as a plain install leaves it: `import distributed` fails."""
    monkeypatch.setitem(sys.modules, "distributed", None)


def test_dask_is_an_extra_not_a_dependency():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert not [d for d in project["dependencies"] if d.startswith("dask")]
    assert any(d.startswith("dask[distributed]") for d in project["optional-dependencies"]["dask"])


@pytest.mark.parametrize("check", [[], ["--check"]])
def test_executor_dask_without_dask_is_one_line_and_exit_2(no_dask, tmp_path, capsys, check):
    code = main(["study", str(STUDY), "--executor", "dask", "--out", str(tmp_path / "out"), *check])
    _, err = capsys.readouterr()
    assert code == 2
    assert err == f"crashnlp: error: --executor dask: dask is not installed ({DASK_EXTRA})\n"
    assert not (tmp_path / "out").exists()


def test_profiles_on_dask_without_dask_are_refused_before_the_fit(no_dask):
    raw = yaml.safe_load(PICKUP.read_text())
    raw["uncertainty"] = {"profile": ["vehicle.crush_offset"], "executor": "dask"}
    problem = problem_from_dict(raw, PICKUP.parent, source=str(PICKUP))
    with pytest.raises(InputError, match=r"uncertainty\.executor: dask is not installed \(pip install 'crashnlp\[dask\]'\)"):
        prepare_case(problem, str(PICKUP))
