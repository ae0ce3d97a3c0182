"""A fit's Python work kept on one piece of CPython's frame stack.

CPython 3.11 to 3.13.0 (measured on 3.11.7, 3.12.1 and 3.13.0) keep a thread's Python
frames in chunks of 16 KiB, and give a chunk back to the system (``munmap``) as soon as the
call that opened it returns: a program that calls in and out across a chunk's edge maps and
unmaps it every time (CPython issue gh-142183; later 3.13 and 3.14 releases keep one spare
chunk, and the reserved frame then costs one map and unmap per call).  JAX's tracing does
that tens of thousands of times per program, and a ``munmap`` made while another thread of
the process runs on another core interrupts that core too, to flush its address
translations (dear on a virtual machine).  A fresh process's first
``fit(analytic_points("f4"))`` on 2 cores unmapped about 72,000 chunks while its threads
traced, compiled and ran programs side by side.

:func:`in_one_chunk` runs a call inside one frame that reserves :data:`RESERVED_SLOTS` of
stack (its code object's stack size; the slots are never written, so their pages never
become resident): CPython opens a chunk of 1 MiB for that frame, and every frame the call
makes below it fits in the rest.  The fit's two entry points (``launch.launch`` and
``assemble.collect``) and the threads it starts run so.  That first call, cache off, three
runs each alternated: 9.4-9.6 s and 16.7-17.1 CPU-seconds before, 8.2-8.6 s and
14.8-15.5 CPU-seconds after, 1,500 unmaps; the warm call unchanged (3.6 s).
"""

from __future__ import annotations

import functools
import types

__all__ = ["RESERVED_SLOTS", "in_one_chunk"]

#: Stack slots (8 bytes each) reserved by the frame a call runs under: 512 KiB, so that
#: CPython opens a 1 MiB chunk for it, leaving about 500 KiB for the frames of the call
#: (a JAX trace's deepest stack takes a few dozen KiB).
RESERVED_SLOTS = 1 << 16


def _call(fn, args, kwargs):
    return fn(*args, **kwargs)


# the same function, its frame reserving RESERVED_SLOTS more stack slots
_call = types.FunctionType(
    _call.__code__.replace(co_stacksize=_call.__code__.co_stacksize + RESERVED_SLOTS),
    globals(),
    "_call",
)


def in_one_chunk(fn):
    """``fn``, called inside a frame that keeps every frame of its call in one chunk of
    CPython's frame stack (the module's docstring says why).  The same arguments, result
    and exceptions."""

    @functools.wraps(fn)
    def call(*args, **kwargs):
        return _call(fn, args, kwargs)

    return call
