"""A call run by ``in_one_chunk`` keeps its Python frames in one chunk of CPython's frame
stack: calls in and out across a chunk's edge no longer map and unmap fresh memory."""

import sys
import threading

import pytest

try:
    import resource
except ImportError:  # not on Windows
    resource = None

from swarmcurves_jax.pystack import in_one_chunk


def _descend(depth: int) -> int:
    return 0 if depth == 0 else _descend(depth - 1) + 1


def _descents(times: int = 2000, depth: int = 300) -> int:
    """``times`` calls ``depth`` frames deep (about 30 KiB of frames, past a 16 KiB chunk)."""
    return sum(_descend(depth) for _ in range(times))


def _page_faults(fn) -> tuple[int, object]:
    """Minor page faults of this thread while ``fn()`` runs (a freshly mapped chunk faults
    when its first frame is written), and ``fn``'s result."""
    before = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt
    result = fn()
    return resource.getrusage(resource.RUSAGE_THREAD).ru_minflt - before, result


@pytest.mark.skipif(
    resource is None
    or not hasattr(resource, "RUSAGE_THREAD")
    or sys.implementation.name != "cpython",
    reason="counts a thread's page faults (Linux) of CPython's frame stack",
)
def test_repeated_deep_calls_map_no_fresh_chunks():
    _page_faults(_descents)  # the interpreter's own first use of its stack
    plain, expected = _page_faults(_descents)
    kept, result = _page_faults(in_one_chunk(_descents))
    assert result == expected == 2000 * 300
    # 2,000 descents past a chunk's edge: a fresh chunk each, its pages faulting (10,000
    # faults on CPython 3.11), or none where CPython keeps a spare chunk; in one chunk, a
    # few pages written once (10)
    assert kept < 50, (kept, plain)
    if sys.version_info < (3, 13):
        assert plain >= 2000, plain

    # the same in a thread of its own (the programs' threads are started so)
    out = {}
    thread = threading.Thread(target=lambda: out.update(kept=_page_faults(in_one_chunk(_descents))))
    thread.start()
    thread.join()
    assert out["kept"][0] < 50, out


def test_same_arguments_result_and_errors():
    def f(a, b=1, *rest, c, **more):
        """Doc."""
        return a, b, rest, c, more

    wrapped = in_one_chunk(f)
    assert wrapped(1, 2, 3, c=4, d=5) == (1, 2, (3,), 4, {"d": 5})
    assert (wrapped.__name__, wrapped.__doc__, wrapped.__wrapped__) == ("f", "Doc.", f)
    with pytest.raises(TypeError, match="missing 1 required keyword-only argument: 'c'"):
        wrapped(1)

    def fails():
        raise ValueError("points must be finite")

    with pytest.raises(ValueError, match="points must be finite"):
        in_one_chunk(fails)()
