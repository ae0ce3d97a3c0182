"""Every export is read back: DXF with ezdxf, SVG parsed, NPZ and JSON loaded."""

import json
import re
import xml.etree.ElementTree as ET

import ezdxf
import numpy as np
import pytest

from swarmcurves_jax import Curve, make_knots
from swarmcurves_jax.export import (
    read_solutions,
    svg_path,
    write_dxf,
    write_json,
    write_npz,
    write_svg,
)

U = np.linspace(0, 1, 1000)


def curves(dim=2):
    rng = np.random.default_rng(1)
    return [
        Curve(3, rng.uniform(-1, 1, (6, dim)), np.ones(6), make_knots(6, 3, False)),
        Curve(
            2,
            rng.uniform(-1, 1, (5, dim)),
            rng.uniform(0.5, 2, 5),
            make_knots(5, 2, True),
            closed=True,
            rational=True,
        ),
        Curve(5, rng.uniform(-1, 1, (7, dim)), np.ones(7), make_knots(7, 5, False)),
    ]


@pytest.mark.parametrize("dim", [2, 3])
def test_dxf_splines_read_back_with_ezdxf(tmp_path, dim):
    cs = curves(dim)
    pts = np.random.default_rng(2).uniform(-1, 1, (7, dim))
    write_dxf(tmp_path / "c.dxf", cs, pts)
    doc = ezdxf.readfile(tmp_path / "c.dxf")
    splines = doc.modelspace().query("SPLINE")
    assert len(splines) == 3 and len(doc.modelspace().query("POINT")) == 7
    for spline, curve in zip(splines, cs):
        assert spline.dxf.degree == curve.degree
        assert bool(spline.dxf.flags & 4) == curve.rational
        tool = spline.construction_tool()
        got = np.array([tool.point(u) for u in U])[:, :dim]
        np.testing.assert_allclose(got, curve.evaluate(U), atol=1e-6)


def _bezier(ctrl, s):
    k = len(ctrl) - 1
    from math import comb

    return sum(comb(k, i) * np.outer(s**i * (1 - s) ** (k - i), ctrl[i]) for i in range(k + 1))


def test_svg_paths_are_exact_beziers_or_say_so(tmp_path):
    cs = curves()
    write_svg(tmp_path / "c.svg", cs, np.zeros((3, 2)))
    root = ET.parse(tmp_path / "c.svg").getroot()
    paths = root.findall(".//{http://www.w3.org/2000/svg}path")
    assert [p.get("id") for p in paths] == ["d3_n6", "d2_n5", "d5_n7"]
    notes = [p.find("{http://www.w3.org/2000/svg}desc").text for p in paths]
    assert "exact" in notes[0] and "approximate (rational)" in notes[1]
    assert "approximate (degree 5)" in notes[2]
    # the cubic: rebuild every Bezier segment from the path data and compare
    nums = [float(x) for x in re.findall(r"-?[\d.]+(?:e-?\d+)?", paths[0].get("d"))]
    pts = np.array(nums).reshape(-1, 2)
    segs = [pts[i : i + 4] for i in range(0, len(pts) - 1, 3)]
    s = np.linspace(0, 1, 40)
    got = np.vstack([_bezier(seg, s) for seg in segs])
    want = np.vstack([cs[0].evaluate((j + s) / len(segs)) for j in range(len(segs))])
    np.testing.assert_allclose(got, want, atol=1e-8)
    with pytest.raises(ValueError, match="SVG is 2D"):
        svg_path(curves(3)[0])


def test_npz_and_json_round_trip(tmp_path):
    cs = curves(3)
    write_npz(tmp_path / "c.npz", cs, np.ones((4, 3)))
    with np.load(tmp_path / "c.npz") as z:
        np.testing.assert_array_equal(z["d2_n5_control_points"], cs[1].control_points)
        np.testing.assert_array_equal(z["d2_n5_weights"], cs[1].weights)
        assert bool(z["d2_n5_closed"]) and z["points"].shape == (4, 3)
    write_json(tmp_path / "s.json", cs, config={"a": 1})
    back = read_solutions(tmp_path / "s.json")
    for a, b in zip(back, cs):
        np.testing.assert_array_equal(a.evaluate(U), b.evaluate(U))


@pytest.mark.parametrize(
    "edit,message",
    [
        (lambda d: d.update(schema_version=99), "schema_version 99 is not supported"),
        (lambda d: d["solutions"][1].pop("knots"), "solution 1 is damaged: .*missing key"),
        (lambda d: d["solutions"][0].update(weights=[1, -1, 1, 1, 1, 1]), "solution 0 is damaged"),
        (lambda d: d["solutions"][0].update(degree=9), "solution 0 is damaged"),
        (lambda d: d["solutions"][2].update(schema_version=3), "solution 2 is damaged"),
        (lambda d: d.pop("solutions"), "no 'solutions' list"),
    ],
)
def test_damaged_solutions_are_refused_whole(tmp_path, edit, message):
    write_json(tmp_path / "s.json", curves())
    doc = json.loads((tmp_path / "s.json").read_text())
    edit(doc)
    (tmp_path / "s.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=message):
        read_solutions(tmp_path / "s.json")


def test_truncated_json_is_refused(tmp_path):
    write_json(tmp_path / "s.json", curves())
    text = (tmp_path / "s.json").read_text()
    (tmp_path / "s.json").write_text(text[: len(text) // 2])
    with pytest.raises(ValueError, match="not a readable solutions.json"):
        read_solutions(tmp_path / "s.json")
