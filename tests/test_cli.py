"""The command line, end to end in a subprocess, and its config errors (exit code 2)."""

import json
import re
import subprocess
import sys

import numpy as np
import pytest

from swarmcurves_jax import Curve
from swarmcurves_jax.run import check_config, ConfigError, main


def run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "swarmcurves_jax.run", *args],
                          capture_output=True, text=True, cwd=cwd, timeout=300)


def test_yaml_config_writes_loadable_solutions(tmp_path):
    pts = np.c_[np.cos(np.linspace(0, 5, 80)), np.sin(np.linspace(0, 5, 80)), np.linspace(0, 1, 80)]
    np.savetxt(tmp_path / "pts.csv", pts, delimiter=",", header="x,y,z", comments="")
    (tmp_path / "job.yaml").write_text(
        f"input: {tmp_path / 'pts.csv'}\ncps: 5-6\ndegrees: [2, 3]\niterations: 60\nout: {tmp_path / 'o'}\n"
    )
    proc = run(str(tmp_path / "job.yaml"))
    assert proc.returncode == 0, proc.stderr
    assert "best: degree" in proc.stdout and proc.stdout.count("\n") >= 6
    doc = json.loads((tmp_path / "o" / "solutions.json").read_text())
    curves = [Curve.from_dict(d) for d in doc["solutions"]]
    assert [(c.degree, c.n_ctrl) for c in curves] == [(2, 5), (2, 6), (3, 5), (3, 6)]
    assert curves[0].dim == 3 and doc["config"]["iterations"] == 60
    again = run(str(tmp_path / "job.yaml"))
    assert again.returncode == 2 and "pass --force" in again.stderr
    assert run(str(tmp_path / "job.yaml"), "--force").returncode == 0


def test_bare_run_fits_the_builtin_example(capsys):
    assert main(["--iterations", "30"]) == 0
    out = capsys.readouterr().out
    assert "200 points from f4, open" in out and "best: degree 3" in out


@pytest.mark.parametrize(
    "raw,message",
    [
        ({"iteration": 5}, "unknown config key 'iteration' (did you mean 'iterations'?)"),
        ({"cps": "a-b"}, "cps: expected an int, a list or a range"),
        ({"particles": 0}, "particles: expected an integer >= 1"),
        ({"rational": "yes"}, "rational: expected true or false"),
        ({"tol": -1}, "tol: expected a number >= 0 or null"),
    ],
)
def test_bad_config_values(raw, message):
    with pytest.raises(ConfigError, match=re.escape(message)):
        check_config(raw)


def test_bad_files_exit_2_with_the_line(tmp_path):
    (tmp_path / "bad.txt").write_text("x y\n1 2\n3 4 5\n")
    (tmp_path / "nan.txt").write_text("1 2\nnan 4\n")
    cases = [
        (["--input", str(tmp_path / "bad.txt")], "bad.txt:3: 3 columns, expected 2"),
        (["--input", str(tmp_path / "nan.txt")], "nan.txt:2: NaN or inf"),
        (["--input", str(tmp_path / "missing.csv")], "no such file"),
        (["--cps", "3", "--degrees", "3"], "3 control points are too few"),
    ]
    for args, message in cases:
        proc = run(*args, "--iterations", "5")
        assert proc.returncode == 2 and message in proc.stderr, proc.stderr
