"""benchmarks/physics_step_check.py answers bad input in one line with exit status 2, before any
rollout is compiled."""

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def script():
    spec = importlib.util.spec_from_file_location(
        "physics_step_check", ROOT / "benchmarks/physics_step_check.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize(
    "argv, says",
    [
        (["--every", "0"], "--every is 0"),
        (["--run", "results/no_such_run"], "results/no_such_run is not a run directory"),
        (["--dt", "0.003"], "--dt 0.003: env.ctrl_dt must be a whole multiple"),
        (["--dt", "fast"], "invalid float value"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(script, capsys, argv, says):
    assert script.main(argv) == 2
    out = capsys.readouterr()
    lines = out.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and says in lines[0], out.err
