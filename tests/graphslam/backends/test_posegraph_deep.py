"""A 100 000-pose chain (issue 34): gtsam's recursive elimination overflowed the
main thread's stack in batch LM and killed the interpreter (SIGSEGV); the deep
gtsam calls now run on a deep-stack thread (``graphslam.backends.deep_stack``).
The chain itself runs in the hostile pass (its attack "100 000-pose chain, --backend
batch", tests/repo/test_hostile_pass.py: a subprocess, so that a crash fails the test
instead of pytest; every pose solved to the zero cost); here, the deep-stack call."""

from __future__ import annotations

import pytest

from graphslam.backends import deep_stack


def test_deep_stack_call_returns_and_raises_as_a_direct_call():
    assert deep_stack.call(sum, [1, 2, 3]) == 6
    with pytest.raises(ZeroDivisionError):
        deep_stack.call(lambda: 1 / 0)
