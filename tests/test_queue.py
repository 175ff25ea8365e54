"""The work queue behind batched fits (rbjax.identification._queue): every member stops on its own.

A toy member machine whose step counts and restarts are known in advance: member
``i`` needs ``need(i)`` steps per round and ``rounds(i)`` extra rounds, so each
output can be checked exactly, whatever the slots, stages and round length.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rbjax.identification._queue import run_queue, stage_widths


def need(i):
    return (i * 7) % 13 + 1  # 1..13 steps, in no particular order


def rounds(i):
    return jnp.where(i % 3 == 0, 1, 0)  # every third member is restarted once


def _machine():
    def start(i):
        zero = jnp.zeros_like(i)
        return dict(i=i, k=zero, round=zero, total=zero)

    def advance(s):
        return dict(s, k=s["k"] + 1)

    def running(s):
        return s["k"] < need(s["i"])

    def retire(s):
        total = s["total"] + s["k"]
        again = s["round"] < rounds(s["i"])
        restarted = dict(s, k=jnp.zeros_like(s["k"]), round=s["round"] + 1, total=total)
        return again, restarted, dict(i=s["i"], steps=total, round=s["round"])

    return start, advance, running, retire


@pytest.mark.parametrize(
    ("n", "widths", "k"),
    [(50, (16, 4), 3), (50, (16, 4, 1), 1), (7, (8, 2), 5), (1, (1,), 100), (40, (40,), 2)],
)
def test_each_member_gets_its_own_steps_and_rounds(n, widths, k):
    out = jax.jit(lambda: run_queue(n, *_machine(), widths=widths, steps_per_round=k))()
    i = np.arange(n)
    np.testing.assert_array_equal(out["i"], i)  # every member once, in its own row
    expected = np.array([need(j) * (1 + rounds(j)) for j in i])
    np.testing.assert_array_equal(out["steps"], expected)
    np.testing.assert_array_equal(out["round"], [int(rounds(j)) for j in i])


def test_stage_widths_shrink_by_four_down_to_the_last():
    assert stage_widths(1000) == (128, 32, 8)
    assert stage_widths(100) == (100, 25, 6)
    assert stage_widths(3) == (3,)
    assert stage_widths(1) == (1,)
