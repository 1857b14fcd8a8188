"""Arguments packed once for compiled calls that repeat them at every step.

numba unboxes every array of a call's arguments (tuples recursively) at every dispatch,
about 60 ns each: the batch core's end of a control period passed some 65, its
substep's transmission call twenty, g(q) of a [`SerialChain`][elastic_gym.model.SerialChain]
twenty. A `Packed` holds such a tuple on numba's heap: a kernel taking it unboxes
one pointer and reads ``packed.values``. The arrays are shared, not copied: changes made
in place on either side are seen by the other; an array rebound in Python is not (pack
again).
"""

from __future__ import annotations

from numba import njit, types
from numba.experimental import structref


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
