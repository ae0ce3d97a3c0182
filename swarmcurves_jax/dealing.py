"""Dealing a call's swarms over several CPU devices, one program each.

XLA:CPU runs one program on all cores, but several independent programs on as many CPU
devices use them better (:func:`swarmcurves_jax.devices.cpu_devices`), so a lone fit deals
its swarms into sets of similar cost.  A swarm's result does not depend on the dealing:
each set keeps its degree groups' search samples and spans (:func:`part_groups`), and a
swarm never runs alone in a group that has several in the call (:func:`widen`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["swarm_costs", "split_swarms", "part_groups", "widen"]


def swarm_costs(pairs, groups, closed: bool, columns: int) -> np.ndarray:
    """Each swarm's fitness work per point, in search samples: a spline's samples, plus
    ``5 + spans (k + 3) columns / 5`` for its span selects and Newton steps (``spans``: its
    group's, ``columns``: D, + 1 if rational); a polygon's 1.25 a segment (its search is
    its distance, :func:`~swarmcurves_jax.fitness.polyline_distances`).  Fitted to the
    CPU time of W1's groups: a sample 3.4 us a swarm and iteration, the rest
    20 samples' worth for the quadratics (8 spans), 22 for the cubics (7), a polygon 11.5
    for 9 segments.  ``benchmarks/bench_w1.py`` times the split it gives."""
    cost = np.zeros(len(pairs))
    for k, i, j, samples in groups:
        spans = max(n if closed else n - k for _, n in pairs[i:j])
        cost[i:j] = 1.25 * samples if k == 1 else samples + 5 + spans * (k + 3) * columns / 5
    return cost


def split_swarms(groups, parts: int, cost: np.ndarray) -> list[np.ndarray]:
    """The swarms of a call dealt into at most ``parts`` sets of similar ``cost`` (per
    swarm, :func:`swarm_costs`), each set in call order.  Each set compiles a program
    with its own degree groups, so whole groups are dealt first (the costliest to the
    least loaded set); then single swarms move from the most to the least loaded set
    while that set stays below the other: freely into a group it already has, and to
    start a new group there only 5 % below.  A set's load counts the copy that
    :func:`widen` adds to a swarm left alone in its group.
    """
    count = min(parts, groups[-1][2])
    sets = [[] for _ in range(count)]
    group = np.zeros(groups[-1][2], int)
    for g, (_, i, j, _) in enumerate(groups):
        group[i:j] = g
    load = lambda s: cost[widen(np.array(sorted(s), int), groups)].sum()  # noqa: E731
    for k, i, j, _ in sorted(groups, key=lambda g: (-cost[g[1]] * (g[2] - g[1]), g[1])):
        sets[int(np.argmin([load(s) for s in sets]))] += range(i, j)
    while True:
        loads = [load(s) for s in sets]
        top, low = int(np.argmax(loads)), int(np.argmin(loads))
        best = None
        for i in sorted(sets[top], key=lambda i: (-cost[i], i)):
            known = group[i] in group[sets[low]]
            rest = [x for x in sets[top] if x != i]
            below = load(sets[low] + [i]) < loads[top] * (1.0 if known else 0.95)
            if below and load(rest) < loads[top]:
                best = i
                break
        if best is None:
            return [np.array(sorted(x)) for x in sets if x]
        sets[top].remove(best)
        sets[low].append(best)


def part_groups(groups, chosen: np.ndarray):
    """:func:`~swarmcurves_jax.prepare.degree_groups` of the swarms ``chosen``, each group
    keeping the whole call's search samples (so a swarm's result does not depend on the
    split), and per
    group its index in ``groups`` and the positions of its chosen swarms there."""
    out, within = [], []
    for g, (k, i, j, samples) in enumerate(groups):
        mine = np.flatnonzero((chosen >= i) & (chosen < j))
        if len(mine):
            out.append((k, int(mine[0]), int(mine[-1]) + 1, samples))
            within.append((g, chosen[mine] - i))
    return tuple(out), within


def widen(chosen: np.ndarray, groups) -> np.ndarray:
    """The swarms ``chosen`` (in call order) as a set runs them: a swarm alone in its degree
    group gets a copy beside it (its results dropped) where the call's group has several.
    XLA compiles a vmap of one swarm differently (its batch axis removed), and it rounds
    differently; a vmap of two or more rounds as the whole group does, so a swarm's
    result does not depend on the dealing."""
    out = []
    for _, i, j, _ in groups:
        mine = chosen[(chosen >= i) & (chosen < j)]
        out += [*mine, *mine] if len(mine) == 1 and j - i > 1 else list(mine)
    return np.array(out, int)
