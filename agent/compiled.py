"""How the library compiles its inner loops: numba, cached on disk beside the code they serve.

Some loops iterate or branch per sample: perception's weighted line fit re-weights until its
normal settles and its circle fit takes Gauss-Newton steps; the simulator casts each beam
against a handful of obstacles, checks its return path and filters a few thousand steps a
sweep. Written in numpy, each step is a dozen small-array calls costing about a microsecond
each whatever their size, so call overhead dominated. Those loops are compiled with numba and
run over the samples directly.
Each sits in a ``*_kernels`` module beside the code it serves (the line fits' beside
:mod:`agent.perception.features.lines`, the ray caster's beside :mod:`agent.sim.raycast`,
...), apart from that code so that editing it leaves the compiled cache valid.

Compiled code is cached on disk beside each module: the first use on a new machine compiles
it (``run.py`` does that at install, see :func:`agent.perception.warm_up` and
:func:`agent.sim.simulator.warm_up`), a new process loads it on first use (numba's import
and set-up cost a process about half a second, each kernel a few milliseconds more).

Each kernel computes what its docstring says, in the same order of operations as the
formulas that document it beside it; the tests compare them with plain numpy references.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

_F = TypeVar("_F", bound=Callable[..., Any])


def compiled(fn: _F) -> _F:
    """Compile ``fn`` with numba (nopython, cached); IEEE arithmetic, numpy's error model
    (a division by zero gives inf or NaN, as in numpy, rather than raising)."""
    return cast(_F, numba.njit(cache=True, error_model="numpy")(fn))


def compiled_inline(fn: _F) -> _F:
    """:func:`compiled`, for a small helper of other kernels: its body is inlined where it is
    called, so that a call per sample costs no argument passing (each array argument of a
    compiled call is reference-counted, which costs more than a short helper's work)."""
    return cast(_F, numba.njit(cache=True, error_model="numpy", inline="always")(fn))


def fresh_floats(values: ArrayLike) -> NDArray[np.float64]:
    """A contiguous, writeable float64 copy of ``values``: the one array type a kernel is
    compiled and cached for (a read-only array, as a decoded message holds, or another
    layout would compile it anew in each process)."""
    return np.array(values, dtype=np.float64, order="C")
