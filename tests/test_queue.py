"""The work queue behind batched fits (rbjax.identification._queue): every member stops on its own.

A toy member machine whose step counts and restarts are known in advance: member
``i`` needs ``need(i)`` steps per round and ``rounds(i)`` extra rounds, so each
output can be checked exactly, whatever the slots, chunks and round length.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rbjax.identification._queue import run_queue


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
    ("n", "slots", "chunk", "k", "retire"),
    [
        (50, 16, 4, 3, 4),
        (50, 16, 4, 1, 3),  # retiring 3 at a time: 16 slots retire 2 at a time (whole chunks)
        (50, 12, 8, 2, 4),  # 12 slots in chunks of 8: 16 slots, two whole chunks
        (7, 8, 2, 5, 4),
        (1, 1, 1, 100, 4),
        (40, 40, 40, 2, 1),
    ],
)
def test_each_member_gets_its_own_steps_and_rounds(n, slots, chunk, k, retire):
    run = lambda: run_queue(n, *_machine(), slots=slots, chunk=chunk, steps_per_round=k, retire_chunk=retire)
    out = jax.jit(run)()
    i = np.arange(n)
    np.testing.assert_array_equal(out["i"], i)  # every member once, in its own row
    expected = np.array([need(j) * (1 + rounds(j)) for j in i])
    np.testing.assert_array_equal(out["steps"], expected)
    np.testing.assert_array_equal(out["round"], [int(rounds(j)) for j in i])


def test_one_step_per_program():
    # the member's step is what the fit's model compiles into: it must appear once in the program
    # (not once per stage), whatever the slots and chunks
    start, advance, running, retire = _machine()
    calls = []

    def counted(s):
        calls.append(1)  # once per trace of the step
        return advance(s)

    jax.jit(lambda: run_queue(50, start, counted, running, retire, slots=32, chunk=8, steps_per_round=2)).lower()
    assert len(calls) == 1
