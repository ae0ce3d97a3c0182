"""The command line end to end (temp folders), and its refusals (exit code 2).

A run that a test needs as a process (the module's entry point, signals, a kill) is a
subprocess; the others call :func:`swarmcurves_jax.run.main` in the test's process,
which is what the entry point runs, without a new process's imports and compilations."""

import csv
import json
import os
import re
import select
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ET

import ezdxf
import numpy as np
import pytest
import yaml

from swarmcurves_jax.config import ConfigError, check_config
from swarmcurves_jax.datasets import random_bspline_points, read_outlines
from swarmcurves_jax.export import read_solutions
from swarmcurves_jax.run import main


def run(*args, cwd=None, timeout=300):
    return subprocess.run(
        [sys.executable, "-m", "swarmcurves_jax.run", *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=timeout,
    )


def call(capsys, *args):
    """``main(args)`` in this process, shaped like :func:`run`'s result."""
    capsys.readouterr()
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return subprocess.CompletedProcess(args, code, out, err)


@pytest.mark.parametrize(
    "dim,closed,rational,suffix",
    [
        (2, False, False, ".csv"),
        (2, True, True, ".txt"),
        (3, False, True, ".npy"),
        (3, True, False, ".xyz"),
    ],
)
def test_end_to_end_every_output_reads_back(tmp_path, capsys, dim, closed, rational, suffix):
    pts, _ = random_bspline_points(6, 3, closed, num_points=90, dim=dim, seed=4)
    pts = pts * 30 + 7
    src = tmp_path / f"pts{suffix}"
    if suffix == ".npy":
        np.save(src, pts)
    else:
        np.savetxt(
            src,
            pts,
            delimiter="," if suffix == ".csv" else " ",
            header="x,y" if suffix == ".csv" else "",
            comments="",
        )
    cfg = {
        "input": str(src),
        "closed": closed,
        "rational": rational,
        "cps": "5-6",
        "degrees": [2, 3],
        "iterations": 60,
        "refine": "none",  # the outputs are checked here; the bare run polishes
        "out": str(tmp_path / "out"),
        "figures": ["best", "sparsest", "error_vs_cps"],
    }
    (tmp_path / "job.yaml").write_text(yaml.safe_dump(cfg))
    job = [tmp_path / "job.yaml", "--quiet"]  # the first case as a process, the others in ours
    proc = run(*map(str, job)) if suffix == ".csv" else call(capsys, *job)
    assert proc.returncode == 0, proc.stderr
    assert "<- best" in proc.stdout and "stopped on the iteration limit (60)" in proc.stdout
    out = tmp_path / "out"
    curves = read_solutions(out / "solutions.json")
    doc = json.loads((out / "solutions.json").read_text())
    assert {"swarmcurves_jax", "jax", "config", "seed", "wall_time"} <= set(doc)
    assert [(c.degree, c.n_ctrl) for c in curves] == [(2, 5), (2, 6), (3, 5), (3, 6)]
    assert all(c.closed == closed and c.rational == rational and c.dim == dim for c in curves)
    with np.load(out / "solutions.npz") as z:
        np.testing.assert_array_equal(z["d3_n6_control_points"], curves[3].control_points)
    splines = ezdxf.readfile(out / "curves.dxf").modelspace().query("SPLINE")
    assert len(splines) == 4
    u = np.linspace(0, 1, 200)
    got = np.array([splines[3].construction_tool().point(x) for x in u])[:, :dim]
    np.testing.assert_allclose(got, curves[3].evaluate(u), atol=1e-6)
    if dim == 2:
        assert len(ET.parse(out / "curves.svg").getroot().findall(".//{*}path")) == 4
    else:
        assert not (out / "curves.svg").exists() and "no SVG for 3D" in proc.stdout
    for png in ("best.png", "error_vs_cps.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    again = call(capsys, *job)
    assert again.returncode == 2 and "pass --force" in again.stderr
    assert call(capsys, *job, "--force").returncode == 0


def test_bare_run_fits_the_builtin_example(capsys):
    assert main(["--iterations", "30", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "200 points from f4, open" in out and "best: degree 3" in out


def test_help_lists_every_key():
    proc = run("--help")
    assert proc.returncode == 0
    for key in check_config({}):
        assert key in proc.stdout


@pytest.mark.parametrize(
    "raw,message",
    [
        ({"iteration": 5}, "unknown config key 'iteration' (did you mean 'iterations'?)"),
        ({"degres": 3}, "unknown config key 'degres' (did you mean 'degrees'?)"),
        ({"cps": "a-b"}, "cps: expected an int, a list of ints or a range 'A-B'"),
        ({"cps": []}, "cps: expected an int, a list of ints or a range 'A-B'"),
        ({"degrees": True}, "degrees: expected an int, a list of ints"),
        ({"particles": 0}, "particles: expected an integer >= 1"),
        ({"iterations": 2.5}, "iterations: expected an integer >= 1"),
        ({"rational": "yes"}, "rational: expected true or false"),
        ({"closed": 1}, "closed: expected true or false or null"),
        ({"tol": -1}, "tol: expected a number >= 0 or null"),
        ({"v_max": 0}, "v_max: expected a number > 0"),
        ({"inertia": "fast"}, "inertia: expected a finite number"),
        ({"seed": -3}, "seed: expected an integer >= 0"),
        ({"init": "random"}, "init: expected one of lsq, uniform"),
        ({"refine": True}, "refine: expected one of lm, lbfgs, none"),
        ({"free_knots": "no"}, "free_knots: expected true or false"),
        ({"figures": ["best", "nice"]}, "figures: expected a list from best, sparsest, all"),
        ({"exports": ["step"]}, "exports: expected a list from json, npz, dxf, svg"),
        ({"input": 5}, "input: expected a non-empty string"),
    ],
)
def test_bad_config_values(raw, message):
    with pytest.raises(ConfigError, match=re.escape(message)):
        check_config(raw)


def test_bad_configs_and_files_exit_2_with_one_clear_line(tmp_path, capsys):
    (tmp_path / "ragged.txt").write_text("x y\n1 2\n3 4 5\n")
    (tmp_path / "nan.txt").write_text("1 2\nnan 4\n")
    (tmp_path / "word.csv").write_text("1,2\n3,four\n")
    (tmp_path / "wide.txt").write_text("1 2 3 4\n")
    (tmp_path / "empty.txt").write_text("# nothing\n")
    (tmp_path / "few.txt").write_text("0 0\n1 1\n2 0\n")
    (tmp_path / "bad.yaml").write_text("cps: [4, 5\n")
    (tmp_path / "list.yaml").write_text("- 1\n- 2\n")
    (tmp_path / "typo.yaml").write_text("iteratons: 5\n")
    np.save(tmp_path / "flat.npy", np.zeros(10))
    (tmp_path / "nodata.yaml").write_text(f"input: outline:Goldi_path0\ndata_dir: {tmp_path}\n")
    cases = [
        (["--input", str(tmp_path / "ragged.txt")], "ragged.txt:3: 3 columns, expected 2"),
        (["--input", str(tmp_path / "nan.txt")], "nan.txt:2: NaN or inf"),
        (["--input", str(tmp_path / "word.csv")], "word.csv:2: not a number"),
        (["--input", str(tmp_path / "wide.txt")], "wide.txt:1: 4 columns, expected 2 or 3"),
        (["--input", str(tmp_path / "empty.txt")], "holds no points"),
        (["--input", str(tmp_path / "few.txt")], "3 points are too few for 10 control points"),
        (["--input", str(tmp_path / "flat.npy")], "expected a numeric (N, 2) or (N, 3) array"),
        (["--input", str(tmp_path / "missing.csv")], "input: no such file"),
        ([str(tmp_path / "nodata.yaml")], "data_dir: no outlines/outlines.npz under"),
        (["--cps", "3", "--degrees", "3"], "3 control points are too few"),
        ([str(tmp_path / "bad.yaml")], "is not valid YAML"),
        ([str(tmp_path / "list.yaml")], "must hold a mapping of keys"),
        (
            [str(tmp_path / "typo.yaml")],
            "unknown config key 'iteratons' (did you mean 'iterations'?)",
        ),
        ([str(tmp_path / "none.yaml")], "config: no such file"),
    ]
    for i, (args, message) in enumerate(cases):
        args = [*args, "--iterations", "5", "--quiet", "--out", str(tmp_path / "o")]
        proc = run(*args, timeout=120) if i == 0 else call(capsys, *args)  # one as a process
        assert proc.returncode == 2, (args, proc.stderr)
        assert message in proc.stderr and proc.stderr.count("\n") == 1, (args, proc.stderr)
        assert not (tmp_path / "o").exists()  # nothing written, nothing started


def test_outline_datasets_load_from_data_dir(tmp_path, capsys):
    (tmp_path / "outlines").mkdir()
    ring = np.c_[np.cos(np.linspace(0, 6, 40)), np.sin(np.linspace(0, 6, 40))]
    np.savez(tmp_path / "outlines" / "outlines.npz", ring_points=ring, ring_closed=np.array(True))
    (tmp_path / "job.yaml").write_text(
        f"input: outline:ring\ndata_dir: {tmp_path}\ncps: 5\niterations: 20\nrefine: none\n"
    )
    assert main([str(tmp_path / "job.yaml"), "--quiet"]) == 0
    assert "40 points from outline:ring, closed" in capsys.readouterr().out
    (tmp_path / "job.yaml").write_text(f"input: outline:square\ndata_dir: {tmp_path}\n")
    assert main([str(tmp_path / "job.yaml"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "no outline 'square'" in err and "have ring" in err


def test_outlines_read_at_either_spacing_or_say_which_is_missing(tmp_path):
    (tmp_path / "outlines").mkdir()
    even, uneven = np.zeros((5, 2)), np.ones((5, 2))
    arrays = dict(a_points=even, a_points_random=uneven, a_closed=np.array(False))
    np.savez(tmp_path / "outlines" / "outlines.npz", **arrays, b_points=even, b_closed=True)
    assert read_outlines(tmp_path)["b"]["points"].tolist() == even.tolist()
    with pytest.raises(ValueError, match=r"no random-spaced points \('b_points_random'\) for b$"):
        read_outlines(tmp_path, "random")
    with pytest.raises(ValueError, match="spacing must be one of even, random, got 'odd'"):
        read_outlines(tmp_path, "odd")
    np.savez(tmp_path / "outlines" / "outlines.npz", **arrays)
    assert read_outlines(tmp_path, "random")["a"]["points"].tolist() == uneven.tolist()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_interrupt_keeps_the_best_so_far_and_writes_complete_files(tmp_path, sig):
    # The command line as a shell's foreground job starts it: Python's own SIGINT handler.
    # A test run started as a background job without job control ignores SIGINT, and a
    # child inherits that (a test run so launched timed out here).
    start = "import runpy, signal; signal.signal(signal.SIGINT, signal.default_int_handler); "
    start += "runpy.run_module('swarmcurves_jax.run', run_name='__main__')"
    args = ["--iterations", "200000", "--out", str(tmp_path / "o")]
    with subprocess.Popen(
        [sys.executable, "-c", start, *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=dict(os.environ, PYTHONFAULTHANDLER="1"),  # SIGABRT prints every thread's stack
    ) as proc:  # closes the pipes and reaps the process even when the test fails
        try:
            # Signal once the progress bar shows a finished chunk: after compiling (a fixed
            # sleep raced the compilation on a slow machine), while the swarm runs.
            seen, deadline = "", time.monotonic() + 120
            while not re.search(r"[1-9]\d*/200000", seen) and time.monotonic() < deadline:
                if select.select([proc.stderr], [], [], 1.0)[0]:
                    seen += os.read(proc.stderr.fileno(), 4096).decode(errors="replace")
            assert re.search(r"[1-9]\d*/200000", seen), seen[-2000:]
            proc.send_signal(sig)
            try:
                out, err = proc.communicate(timeout=120)
            except subprocess.TimeoutExpired:  # say where it is stuck
                proc.send_signal(signal.SIGABRT)
                err = proc.communicate(timeout=30)[1]
                pytest.fail(f"still running 120 s after {sig.name}; its stacks:\n{err[-8000:]}")
        finally:
            if proc.poll() is None:  # never leave a 200,000-iteration run behind
                proc.kill()
    assert proc.returncode == 0, err
    assert "stopped on an interrupt (best solutions so far)" in out
    curves = read_solutions(tmp_path / "o" / "solutions.json")
    assert len(curves) == 7 and all(np.isfinite(c.error) for c in curves)
    assert not list((tmp_path / "o").glob(".*.part"))


def _write_curves(folder):
    """Three point files: two open 2-D curves of different lengths and a 3-D helix."""
    folder.mkdir()
    s = np.linspace(0, 1, 50)
    np.savetxt(folder / "arc.csv", np.c_[s, s**2], delimiter=",", header="x,y", comments="")
    np.savetxt(folder / "wave.txt", np.c_[s[:40], np.sin(4 * s[:40])])
    np.save(folder / "helix.npy", np.c_[np.cos(4 * s), np.sin(4 * s), s])
    (folder / "notes.md").write_text("not points")
    return ["arc", "helix", "wave"]


BATCH_ARGS = ("--cps", "4-5", "--iterations", "30", "--particles", "16", "--quiet")


def _quick(folder, text=""):
    """A config that adds ``refine: none`` to ``text``: the batch tests check what is read
    and written, and fit_many's polish has its own tests."""
    path = folder / "quick.yaml"
    path.write_text(text + "refine: none\n")
    return str(path)


def test_batch_folder_writes_a_result_per_curve_and_a_summary(tmp_path, capsys):
    names = _write_curves(tmp_path / "scans")
    out, job = tmp_path / "o", _quick(tmp_path)
    assert main([job, "--input", str(tmp_path / "scans"), *BATCH_ARGS, "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "3 of 3 curves in" in printed and "padding:" in printed
    with open(out / "summary.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["input"] for r in rows] == names
    assert [int(r["points"]) for r in rows] == [50, 50, 40]
    assert [r["bucket"] for r in rows] == ["64", "64", "48"]
    for row in rows:
        curves = read_solutions(out / row["folder"] / "solutions.json")
        assert [c.n_ctrl for c in curves] == [4, 5]
        best = min(curves, key=lambda c: c.mean_deviation)  # FitResult.best's measure
        assert float(row["best_mean_deviation"]) == pytest.approx(best.mean_deviation, rel=1e-6)
        assert float(row["best_error"]) == pytest.approx(best.error, rel=1e-6)
        assert curves[0].dim == (3 if row["input"] == "helix" else 2)
    # the same run again is refused before any work; a glob picks its files only
    assert main([job, "--input", str(tmp_path / "scans"), *BATCH_ARGS, "--out", str(out)]) == 2
    assert "already holds summary.csv" in capsys.readouterr().err
    glob_out = tmp_path / "g"
    pattern = str(tmp_path / "scans" / "*.csv")
    assert main([job, "--input", pattern, *BATCH_ARGS, "--out", str(glob_out)]) == 0
    assert sorted(p.name for p in glob_out.iterdir()) == ["arc", "run.json", "summary.csv"]
    assert json.loads((glob_out / "arc" / "summary.json").read_text())["input"] == "arc"


def test_batch_from_one_npz_and_from_an_outline_pattern(tmp_path, capsys):
    s = np.linspace(0, 1, 50)
    np.savez(tmp_path / "set.npz", left=np.c_[s, s**2], right=np.c_[s, 1 - s**2])
    assert main([_quick(tmp_path), "--input", str(tmp_path / "set.npz"), *BATCH_ARGS]) == 0
    printed = capsys.readouterr().out
    assert "left" in printed and "right" in printed and "2 of 2 curves" in printed
    (tmp_path / "outlines").mkdir()
    ring = np.c_[np.cos(np.linspace(0, 6, 60)), np.sin(np.linspace(0, 6, 60))]
    np.savez(
        tmp_path / "outlines" / "outlines.npz",
        ring_points=ring,
        ring_closed=np.array(True),
        rim_points=ring[:40],
        rim_closed=np.array(False),
    )
    args = ["--input", "outline:r*", *BATCH_ARGS, "--out", str(tmp_path / "o")]
    assert main([_quick(tmp_path, f"data_dir: {tmp_path}\n"), *args]) == 0
    with open(tmp_path / "o" / "summary.csv") as fh:
        rows = {r["input"]: r for r in csv.DictReader(fh)}
    assert rows["ring"]["closed"] == "True" and rows["rim"]["closed"] == "False"


def _files(out):
    """Every result file of a batch folder: its bytes, and its time for the curve files."""
    return {
        str(p.relative_to(out)): (p.read_bytes(), p.stat().st_mtime_ns)
        for p in sorted(out.rglob("*"))
        if p.is_file()
    }


def test_a_killed_batch_resumes_to_the_uninterrupted_result(tmp_path, capsys):
    """SIGKILL a batch part way, resume it: the curves done before the kill are kept
    untouched (not fitted twice), the others fitted, and every result equals an
    uninterrupted run's."""
    s = np.linspace(0, 1, 50)
    curves = {f"c{i:02d}": np.c_[s, np.sin((2 + i / 8) * s)] for i in range(32)}
    np.savez(tmp_path / "set.npz", **curves)
    job = _quick(tmp_path, "figures: []\nexports: [json, npz]\n")
    args = [job, "--input", str(tmp_path / "set.npz"), *BATCH_ARGS]
    args += ["--batch-size", "2"]
    whole, part = tmp_path / "whole", tmp_path / "part"
    assert main([*args, "--out", str(whole)]) == 0
    start = "import runpy; runpy.run_module('swarmcurves_jax.run', run_name='__main__')"
    with subprocess.Popen(
        [sys.executable, "-c", start, *args, "--out", str(part)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    ) as proc:
        deadline = time.monotonic() + 200
        while len(list(part.glob("*/summary.json"))) < 8 and time.monotonic() < deadline:
            assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
            time.sleep(0.02)
        proc.kill()
    done = {p.parent.name for p in part.glob("*/summary.json")}
    assert 8 <= len(done) < 32 and not (part / "summary.csv").exists()
    before = _files(part)
    proc = call(capsys, *args, "--out", part, "--resume", "--force")
    assert proc.returncode == 2 and "give one" in proc.stderr
    proc = call(capsys, *args, "--out", part, "--resume", "--iterations", "31")
    assert proc.returncode == 2 and "other values of iterations" in proc.stderr
    proc = call(capsys, *args, "--out", part, "--resume")
    assert proc.returncode == 0, proc.stderr
    assert "32 of 32 curves in" in proc.stdout
    assert f"({len(done)} kept from the earlier run)" in proc.stdout
    after = _files(part)
    kept = [f for f in before if f.split("/")[0] in done]
    assert kept and all(after[f] == before[f] for f in kept)  # untouched: not refitted
    ours, theirs = _files(whole), after
    assert sorted(ours) == sorted(theirs)  # no unfinished writes (.part files) left
    for name in ours:
        if name.endswith(".npz"):
            with np.load(whole / name) as a, np.load(part / name) as b:
                assert all(np.array_equal(a[k], b[k]) for k in a.files), name
        elif name.endswith("solutions.json"):
            a, b = (json.loads((out / name).read_text()) for out in (whole, part))
            for doc in (a, b):  # the run's time and folder differ, not the curves
                assert doc.pop("wall_time") > 0 and doc["config"].pop("out")
            assert a == b, name
    rows = [
        list(csv.DictReader((out / "summary.csv").read_text().splitlines()))
        for out in (whole, part)
    ]
    for row in rows[0] + rows[1]:
        row.pop("call")  # which program call ran a curve depends on the run
    assert rows[0] == rows[1]


def test_bad_batch_inputs_exit_2_naming_the_file(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    (tmp_path / "mixed").mkdir()
    (tmp_path / "mixed" / "ok.txt").write_text("0 0\n1 1\n2 0\n3 1\n4 0\n5 1\n")
    (tmp_path / "mixed" / "bad.txt").write_text("0 0\n1 x\n")
    (tmp_path / "short").mkdir()
    (tmp_path / "short" / "tiny.txt").write_text("0 0\n1 1\n2 0\n")
    np.savez(tmp_path / "flat.npz", a=np.zeros(5))
    cases = [
        (tmp_path / "empty", "folder '" + str(tmp_path / "empty") + "' holds no point files"),
        (tmp_path / "nothing*.csv", "no files match"),
        (tmp_path / "mixed", "bad.txt:2: not a number"),
        (tmp_path / "flat.npz", "flat.npz['a']: expected a numeric (N, 2) or (N, 3) array"),
        (tmp_path / "short", "'tiny': 3 points are too few for 10 control points"),
    ]
    for where, message in cases:
        proc = call(capsys, "--input", where, "--quiet", "--out", tmp_path / "o")
        assert proc.returncode == 2, (where, proc.stderr)
        assert message in proc.stderr and proc.stderr.count("\n") == 1, (where, proc.stderr)
        assert not (tmp_path / "o").exists()
