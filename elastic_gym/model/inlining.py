"""A faster copy of the callee in numba's inliner (compile time only; the same IR).

The kernels of [`SerialChain`][elastic_gym.model.SerialChain] and
[`ArmIntegrator`][elastic_gym.model.integrator.ArmIntegrator] inline their helpers
(`inline="always"`). numba's `InlineWorker.inline_ir` first copies the callee's IR, one
`copy.deepcopy` per block; a variable (`ir.Var`) deep-copies its scope, the scope holds
every variable of the function, so each block's copy copies all the function's variables
again: blocks x variables per call site, for a callee that has inlined its own helpers
(the Newton-Euler recursion in the RK4 right-hand side) about half of the compile time
of its callers. `install` makes the blocks copied by one `inline_ir` call from one
scope share one memo, which is what one `copy.deepcopy` of all the blocks together does:
the scope and its variables are copied once per copy of the callee, the copied IR is
equal block by block to the one copied block by block (numba's inliner renames the
callee's variables by name and then gives every block the caller's scope), and so is
the compiled code. Nothing changes when numba no longer copies that way: the shared
memo is used only for `ir.Block`s deep-copied without a memo inside `inline_ir`.
"""

from __future__ import annotations

import copy
import functools
import threading
from typing import Any

from numba.core import inline_closurecall, ir

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
    worker = inline_closurecall.InlineWorker
    return bool(getattr(worker.inline_ir, "__elastic_gym_shared_memo__", False)) and (
        inline_closurecall.copy is _SharedMemoCopy
    )


def install() -> None:
    """Make numba's inliner copy a callee's blocks with one memo per scope (idempotent)."""
    if installed():
        return
    worker = inline_closurecall.InlineWorker
    if not getattr(worker.inline_ir, "__elastic_gym_shared_memo__", False):
        worker.inline_ir = _with_block_memos(worker.inline_ir)  # type: ignore[method-assign]
    inline_closurecall.copy = _SharedMemoCopy  # type: ignore[assignment]
