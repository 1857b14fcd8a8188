"""A faster copy of the callee in numba's inliner (compile time only; the same IR).

The kernels of [`SerialChain`][elastic_gym.model.SerialChain] and
[`ArmIntegrator`][elastic_gym.model.integrator.ArmIntegrator] inline their helpers
(`inline="always"`). numba's `InlineWorker.inline_ir` copies the callee's IR one
`copy.deepcopy` per block; a variable deep-copies its scope, which holds every variable of
the function: blocks x variables per call site, about half of the compile time of the RK4
(the Newton-Euler recursion inlined in its right-hand side). `install` makes the blocks
copied by one `inline_ir` call from one scope share one memo, which is what one
`copy.deepcopy` of all the blocks together does: the copied IR is equal block by block,
and so is the compiled code. On a numba without these internals (`SUPPORTED` versions,
`InlineWorker.inline_ir`, the module's `copy`), `install` does nothing: compiling is
slower, the numbers the same.
"""

from __future__ import annotations

import copy
import functools
import threading
from typing import Any

import numba

try:  # numba's internals: absent or moved in another release, nothing is patched
    from numba.core import inline_closurecall, ir
except ImportError:  # pragma: no cover - depends on the numba release
    inline_closurecall = ir = None  # type: ignore[assignment]

SUPPORTED = ((0, 68), (0, 68))
"""numba releases (major, minor), first and last, whose inliner this was checked against;
another release compiles without the patch."""

_state = threading.local()


def _block_memos() -> dict[int, dict[int, Any]] | None:
    return getattr(_state, "memos", None)


class _SharedMemoCopy:
    """Stands in for the `copy` module in numba's inliner: inside `inline_ir`, blocks of
    one scope are deep-copied with one memo (a block copied twice gets a fresh copy)."""

    copy = staticmethod(copy.copy)

    @staticmethod
    def deepcopy(x: Any, memo: dict[int, Any] | None = None) -> Any:
        memos = _block_memos()
        if memo is None and memos is not None and isinstance(x, ir.Block):
            shared = memos.setdefault(id(x.scope), {})
            if id(x) not in shared:  # not copied before in this call
                memo = shared
        return copy.deepcopy(x, memo)


def _with_block_memos(inline_ir):
    @functools.wraps(inline_ir)
    def wrapper(*args, **kwargs):
        outer = _block_memos()
        _state.memos = {}
        try:
            return inline_ir(*args, **kwargs)
        finally:
            _state.memos = outer

    wrapper.__elastic_gym_shared_memo__ = True
    return wrapper


def installed() -> bool:
    """Whether numba's inliner copies a callee with one memo per scope."""
    worker = getattr(inline_closurecall, "InlineWorker", None)
    inline_ir = getattr(worker, "inline_ir", None)
    return bool(getattr(inline_ir, "__elastic_gym_shared_memo__", False)) and (
        getattr(inline_closurecall, "copy", None) is _SharedMemoCopy
    )


def patchable() -> bool:
    """Whether this numba is one of the `SUPPORTED` releases and has the inliner's
    internals that `install` patches."""
    release = tuple(int(part) for part in numba.__version__.split(".")[:2])
    worker = getattr(inline_closurecall, "InlineWorker", None)
    return (
        SUPPORTED[0] <= release <= SUPPORTED[1]
        and ir is not None
        and callable(getattr(worker, "inline_ir", None))
        and getattr(inline_closurecall, "copy", None) is not None
    )


def install() -> None:
    """Make numba's inliner copy a callee's blocks with one memo per scope (idempotent; a
    no-op where not `patchable`)."""
    if not patchable() or installed():
        return
    worker = inline_closurecall.InlineWorker
    if not getattr(worker.inline_ir, "__elastic_gym_shared_memo__", False):
        worker.inline_ir = _with_block_memos(worker.inline_ir)  # type: ignore[method-assign]
    inline_closurecall.copy = _SharedMemoCopy  # type: ignore[assignment]
