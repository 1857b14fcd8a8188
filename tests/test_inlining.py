"""numba's inliner with one memo per copied callee (elastic_gym.model.inlining): the same IR."""

from __future__ import annotations

import copy

import numpy as np
from numba import njit
from numba.core import inline_closurecall
from numba.core.compiler import run_frontend

from elastic_gym.model import chain, inlining  # noqa: F401  (chain installs it)


def _helper(a, b, out):
    """A helper with loops and branches (several blocks, one scope)."""
    total = 0.0
    for i in range(a.shape[0]):
        if a[i] > b[i]:
            out[i] = a[i] - b[i]
        else:
            out[i] = b[i] * a[i]
        total += out[i]
    return total


def test_installed_by_the_chain_module():
    assert inlining.patchable() and inlining.installed()
    inlining.install()  # idempotent
    assert inlining.installed()


def test_another_numba_is_left_alone(monkeypatch):
    """A numba release outside `SUPPORTED`, or one whose inliner lacks the patched
    internals: `install` changes nothing and raises nothing."""
    worker, release = inline_closurecall.InlineWorker, inlining.numba.__version__
    monkeypatch.setattr(worker, "inline_ir", worker.inline_ir.__wrapped__)
    monkeypatch.setattr(inline_closurecall, "copy", copy)
    monkeypatch.setattr(inlining.numba, "__version__", "0.99.0")
    inlining.install()
    assert not inlining.patchable() and not inlining.installed()
    monkeypatch.setattr(inlining.numba, "__version__", release)
    monkeypatch.delattr(worker, "inline_ir")
    inlining.install()
    assert not inlining.patchable() and not inlining.installed()


def test_a_callee_copy_equals_numbas_block_by_block_copy():
    """Inside `inline_ir`, the blocks of one scope share one memo: one scope copy for all
    blocks (not the original), every block printed the same as numba's own per-block deep
    copy, and a block copied twice in one call is two objects."""
    func_ir = run_frontend(_helper)
    blocks = func_ir.blocks

    def copied():
        deepcopy = inline_closurecall.copy.deepcopy
        ours = {label: deepcopy(block) for label, block in blocks.items()}
        again = deepcopy(next(iter(blocks.values())))
        return ours, again

    ours, again = inlining._with_block_memos(copied)()
    assert len(blocks) > 3
    scopes = {id(block.scope) for block in ours.values()}
    assert len(scopes) == 1 and id(func_ir.blocks[min(blocks)].scope) not in scopes
    for label, block in blocks.items():
        theirs = copy.deepcopy(block)
        assert [str(s) for s in ours[label].body] == [str(s) for s in theirs.body]
        assert [str(s) for s in theirs.body] == [str(s) for s in block.body]
        assert ours[label] is not block
    assert again is not ours[min(ours)]


def test_inlined_helpers_compute_what_python_computes():
    """A kernel inlining a helper in a loop: the same numbers as the helper run in Python."""
    helper = njit(inline="always")(_helper)

    @njit
    def kernel(a, b, out):
        totals = np.empty(a.shape[0])
        for k in range(a.shape[0]):
            totals[k] = helper(a[k], b[k], out[k])
        return totals

    rng = np.random.default_rng(3)
    a, b = rng.normal(size=(4, 5)), rng.normal(size=(4, 5))
    out, expected = np.empty((4, 5)), np.empty((4, 5))
    totals = kernel(a, b, out)
    for k in range(4):
        assert totals[k] == _helper(a[k], b[k], expected[k])
    np.testing.assert_array_equal(out, expected)
