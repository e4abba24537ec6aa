"""Refactorings keep every bit: the runs of tests/bit_identity.py hash as recorded before the run
driver was rewritten (see that module for what is covered and when to re-record)."""
import json

import pytest

import bit_identity

WANT = json.loads(bit_identity.RECORD.read_text())


@pytest.mark.parametrize("name,thunk", bit_identity.cases(), ids=[c[0] for c in bit_identity.cases()])
def test_results_are_bit_identical_to_the_recorded_ones(name, thunk):
    assert name in WANT, f"{name}: no recorded hash (record with python tests/bit_identity.py --record)"
    assert thunk() == WANT[name]


def test_every_recorded_case_still_runs():
    assert sorted(WANT) == sorted(name for name, _ in bit_identity.cases())
