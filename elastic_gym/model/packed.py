"""Arguments packed once for compiled calls that repeat them at every step.

numba unboxes every array of a call's arguments (tuples recursively) at every dispatch,
about 60 ns each: the batch core's end of a control period passed some 65, its
substep's transmission call twenty, g(q) of a [`SerialChain`][elastic_gym.model.SerialChain]
twenty. A `Packed` holds such a tuple on numba's heap: a kernel taking it unboxes
one pointer and reads ``packed.values``. The arrays are shared, not copied: changes made
in place on either side are seen by the other; an array rebound in Python is not (pack
again).

numba's dispatch finds the type of a `Packed` argument the slow way (an exception raised
and cleared, two Python property calls: some 0.7 us a call, ten times an array's);
`direct` gives a kernel's compiled entry point for fixed argument types, which a hot
loop calls without that lookup.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from numba import njit, types
from numba.experimental import structref

try:  # numba's private C helper: absent in another release, `direct` gives the dispatcher
    from numba._dispatcher import compute_fingerprint
except ImportError:  # pragma: no cover - depends on the numba release
    compute_fingerprint = None  # type: ignore[assignment]


@structref.register
class PackedType(types.StructRef):
    """The numba type of a `Packed` (one per type of the packed tuple)."""

    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(typ)) for name, typ in fields)


class Packed(structref.StructRefProxy):
    """A tuple of arrays and scalars (nested tuples too) as one argument of a kernel."""

    def __new__(cls, values: tuple):
        return _pack(values)  # compiled and cached (the proxy's own constructor is not)


structref.define_proxy(Packed, PackedType, ["values"])


@njit(cache=True)
def _pack(values):
    return Packed(values)


_ENTRIES: dict[tuple, Callable[..., Any]] = {}


def _signature_key(value: Any) -> object:
    """What fixes the numba type of an argument: a `Packed`'s type, else numba's own
    fingerprint of the value (arrays: dimensions, layout, dtype, writeable)."""
    if isinstance(value, Packed):
        return value._numba_type_
    return compute_fingerprint(value)


def direct(kernel: Any, *args: Any) -> Callable[..., Any]:
    """`kernel` (an ``njit`` function) compiled for the types of ``args`` (compiled or
    loaded from numba's cache if need be): its entry point, called without numba's
    dispatch. Every later call must pass arguments of exactly these types (the entry
    point does not check them: a float32 or non-contiguous array where the signature has
    a C-contiguous float64 one reads wrong memory). The kernel itself where numba's JIT
    is disabled or this numba lacks the fingerprint helper (dispatch as usual)."""
    if not hasattr(kernel, "compile") or compute_fingerprint is None:
        return kernel  # NUMBA_DISABLE_JIT (a Python function), or numba's own dispatch
    key = (kernel, *map(_signature_key, args))
    entry = _ENTRIES.get(key)
    if entry is None:
        entry = _ENTRIES[key] = kernel.compile(tuple(map(kernel.typeof_pyval, args)))
    return entry
