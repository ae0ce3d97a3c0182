"""Writing curves to files: JSON, NPZ, DXF (ezdxf) and SVG.  The I/O edge of the library.

Every file is written atomically (a temporary file in the same folder, then a rename), so
an interrupted run never leaves a half-written file behind.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import tempfile
from pathlib import Path
from typing import Iterable

import numpy as np

from .curves import READABLE_SCHEMA_VERSIONS, SCHEMA_VERSION, Curve
from .interop import bezier_segments, clamped_form

__all__ = [
    "atomic_write",
    "write_json",
    "read_solutions",
    "write_npz",
    "write_dxf",
    "write_svg",
    "svg_path",
]


@contextlib.contextmanager
def atomic_write(path, mode: str = "w"):
    """Open a temporary file beside ``path``; rename it over ``path`` only on success."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".part")
    try:
        with os.fdopen(fd, mode, **({} if "b" in mode else {"encoding": "utf-8"})) as fh:
            yield fh
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual mode
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_json(path, curves: Iterable[Curve], **meta) -> None:
    """``solutions.json``: ``meta`` (versions, config, ...) plus every curve's ``to_dict``."""
    doc = {"schema_version": SCHEMA_VERSION, **meta, "solutions": [c.to_dict() for c in curves]}
    with atomic_write(path) as fh:
        json.dump(doc, fh, indent=1)


def read_solutions(path) -> list[Curve]:
    """The curves of a ``solutions.json``; a damaged or foreign file raises ``ValueError``."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: not a readable solutions.json ({exc})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("solutions"), list):
        raise ValueError(f"{path}: not a solutions.json (no 'solutions' list)")
    if doc.get("schema_version") not in READABLE_SCHEMA_VERSIONS:
        readable = " or ".join(map(str, READABLE_SCHEMA_VERSIONS))
        raise ValueError(
            f"{path}: schema_version {doc.get('schema_version')!r} is not supported; this "
            f"version reads schema_version {readable}"
        )
    out = []
    for i, d in enumerate(doc["solutions"]):
        try:
            out.append(Curve.from_dict(d))
        except (ValueError, TypeError, KeyError) as exc:
            raise ValueError(f"{path}: solution {i} is damaged: {exc}") from None
    return out


def write_npz(path, curves: Iterable[Curve], points: np.ndarray | None = None) -> None:
    """Arrays ``d{degree}_n{n}_{control_points|weights|knots}`` per curve (+ ``points``)."""
    arrays = {}
    for c in curves:
        tag = f"d{c.degree}_n{c.n_ctrl}"
        arrays[f"{tag}_control_points"] = c.control_points
        arrays[f"{tag}_weights"] = c.weights
        arrays[f"{tag}_knots"] = c.knots
        arrays[f"{tag}_closed"] = np.array(c.closed)
    if points is not None:
        arrays["points"] = np.asarray(points)
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    with atomic_write(path, "wb") as fh:
        fh.write(buf.getvalue())


def write_dxf(path, curves: Iterable[Curve], points: np.ndarray | None = None) -> None:
    """DXF (R2010) with one ``SPLINE`` per curve on layer ``d{degree}_n{n}``.

    Splines are written in clamped form (a closed curve as its equivalent clamped spline,
    whose ends meet) with their knots and, always, their weights: the form every CAD
    program reads.  ``points`` go on layer ``data`` as ``POINT`` entities.
    """
    import ezdxf

    doc = ezdxf.new("R2010")
    msp = doc.modelspace()
    for c in curves:
        t, ctrl, w = clamped_form(c)
        xyz = np.c_[ctrl, np.zeros(len(ctrl))] if ctrl.shape[1] == 2 else ctrl
        layer = f"d{c.degree}_n{c.n_ctrl}{'_closed' if c.closed else ''}"
        spline = msp.add_spline(dxfattribs={"layer": layer})
        spline.dxf.degree = c.degree
        spline.control_points = xyz.tolist()
        spline.knots = t.tolist()
        spline.weights = w.tolist()
        flags = 4 if c.rational else 0  # RATIONAL
        if c.dim == 2:
            flags |= 8  # PLANAR
        spline.dxf.flags = flags
    if points is not None:
        for p in np.asarray(points, dtype=float):
            msp.add_point(
                tuple(p.tolist()) + ((0.0,) if len(p) == 2 else ()), dxfattribs={"layer": "data"}
            )
    buf = io.StringIO()
    doc.write(buf)
    with atomic_write(path) as fh:
        fh.write(buf.getvalue())


def svg_path(curve: Curve, samples: int = 400) -> tuple[str, str]:
    """SVG path data for a 2D curve and a note on how exact it is.

    Non-rational curves of degree <= 3 become exact line / quadratic / cubic Bézier
    commands (knot insertion).  Other curves become a polyline of ``samples`` points per
    knot span, and the note gives its largest deviation from the curve.
    """
    if curve.dim != 2:
        raise ValueError("svg_path: SVG is 2D; this curve has 3 coordinates")
    segs = bezier_segments(curve)
    fmt = lambda p: f"{p[0]:.10g},{p[1]:.10g}"  # noqa: E731
    parts = [f"M {fmt(segs[0][0][0])}"]
    if curve.degree <= 3 and not curve.rational:
        cmd = {1: "L", 2: "Q", 3: "C"}[curve.degree]
        for ctrl, _ in segs:
            parts.append(cmd + " " + " ".join(fmt(p) for p in ctrl[1:]))
        note = "exact: Bezier segments of the B-spline"
    else:
        u = np.linspace(0, 1, samples * len(segs) + 1)
        pts = curve.evaluate(u)
        parts.append("L " + " ".join(fmt(p) for p in pts[1:]))
        mids = curve.evaluate(0.5 * (u[:-1] + u[1:]))
        dev = float(np.max(np.linalg.norm(mids - 0.5 * (pts[:-1] + pts[1:]), axis=1)))
        why = "rational" if curve.rational else f"degree {curve.degree}"
        note = f"approximate ({why}): polyline, largest deviation about {dev:.3g}"
    if curve.closed:
        parts.append("Z")
    return " ".join(parts), note


def write_svg(path, curves: Iterable[Curve], points: np.ndarray | None = None) -> None:
    """SVG with one ``<path>`` per 2D curve (y flipped so shapes stand upright)."""
    curves = list(curves)
    boxes = [c.evaluate(np.linspace(0, 1, 200)) for c in curves]
    if points is not None:
        boxes.append(np.asarray(points, dtype=float)[:, :2])
    allpts = np.vstack(boxes)
    lo, hi = allpts.min(axis=0), allpts.max(axis=0)
    pad = 0.05 * max(float(np.max(hi - lo)), 1e-12)
    lo, hi = lo - pad, hi + pad
    width = float(np.max(hi - lo))
    stroke = f"{width / 400:.6g}"
    lines = [
        '<svg xmlns="http://www.w3.org/2000/svg" '
        f'viewBox="{lo[0]:.10g} {-hi[1]:.10g} {hi[0] - lo[0]:.10g} {hi[1] - lo[1]:.10g}">',
        '<g transform="scale(1,-1)">',
    ]
    for c in curves:
        d, note = svg_path(c)
        lines.append(
            f'<path id="d{c.degree}_n{c.n_ctrl}" d="{d}" fill="none" stroke="black" '
            f'stroke-width="{stroke}"><desc>degree {c.degree}, {c.n_ctrl} control points, '
            f"{note}</desc></path>"
        )
    if points is not None:
        r = f"{width / 300:.6g}"
        lines.append('<g id="data" fill="red">')
        lines += [f'<circle cx="{p[0]:.10g}" cy="{p[1]:.10g}" r="{r}"/>' for p in points]
        lines.append("</g>")
    lines += ["</g>", "</svg>"]
    with atomic_write(path) as fh:
        fh.write("\n".join(lines) + "\n")
