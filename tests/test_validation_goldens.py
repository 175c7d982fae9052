"""Regression goldens (tests/goldens/<backend>.npz). Regenerate deliberately with
`python -m gendr_validation.goldens --regenerate` (it prints the diff first)."""
import os

import pytest

goldens = pytest.importorskip("gendr_validation.goldens")


@pytest.mark.parametrize("backend", sorted(goldens.COMPUTE))
def test_goldens(backend):
    if not os.path.exists(goldens.path(backend)):
        pytest.skip(f"no goldens for {backend}")
    from gendr_validation.hardlimit import usable_backends
    if not usable_backends([backend]):
        pytest.skip(f"backend {backend} unavailable")
    old = goldens.load(backend)
    new = goldens.compute(backend)
    rows = goldens.diff(new, old)
    bad = [r for r in rows if not r[3]]
    assert not bad, bad
    assert len(rows) == len(goldens.CASES) * 4


def test_goldens_small():
    total = sum(os.path.getsize(os.path.join(goldens.GOLDEN_DIR, f)) for f in os.listdir(goldens.GOLDEN_DIR))
    assert total < 1_000_000
