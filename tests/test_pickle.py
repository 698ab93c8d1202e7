"""Matchers and rectifiers pickle and copy (for process pools and Dask workers): the copy has
the same parameters and ``isa`` request, native state of its own, and gives the same output."""

from __future__ import annotations

import concurrent.futures
import copy
import multiprocessing
import pickle
from typing import Any

import numpy as np
import pytest
from synthetic_pairs import shifted_pair

import stereodepth as sd
from stereodepth import _core

LEFT, RIGHT = shifted_pair((37, 61), 5, seed=11, rgb=True)

MATCHERS = [
    pytest.param(lambda: sd.StereoMatcher(num_disparities=16), id="StereoMatcher"),
    pytest.param(
        lambda: sd.StereoMatcher(
            num_disparities=24,
            min_disparity=-4,
            block_size=5,
            cost="sad",
            subpixel="parabola",
            lr_max_diff=None,
            threads=3,
            return_confidence=True,
            channel_order="bgr",
            border="opencv",
            isa="baseline",
        ),
        id="StereoMatcher-options",
    ),
    pytest.param(lambda: sd.SemiGlobalMatcher(num_disparities=16), id="SemiGlobalMatcher"),
    pytest.param(
        lambda: sd.SemiGlobalMatcher(
            num_disparities=20,
            min_disparity=-2,
            p1=20,
            p2=300,
            paths=8,
            subpixel=False,
            median=False,
            fill=True,
            max_memory_mb=64.0,
            threads=2,
            return_confidence=True,
            isa="baseline",
        ),
        id="SemiGlobalMatcher-options",
    ),
]


def same_output(a: Any, b: Any) -> None:
    if isinstance(a, tuple):
        assert isinstance(b, tuple) and len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            np.testing.assert_array_equal(x, y)
    else:
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("make", MATCHERS)
@pytest.mark.parametrize(
    "clone",
    [
        pytest.param(lambda m: pickle.loads(pickle.dumps(m)), id="pickle"),
        pytest.param(lambda m: pickle.loads(pickle.dumps(m, protocol=2)), id="pickle-2"),
        pytest.param(copy.copy, id="copy"),
        pytest.param(copy.deepcopy, id="deepcopy"),
    ],
)
def test_matcher_round_trip(make: Any, clone: Any) -> None:
    m = make()
    want = m.compute(LEFT, RIGHT)
    c = clone(m)
    assert type(c) is type(m)
    assert c.params == m.params
    assert c.isa == m.isa
    assert c._isa_arg == m._isa_arg
    assert c._native is not m._native  # buffers of its own
    same_output(c.compute(LEFT, RIGHT), want)
    same_output(m.compute(LEFT, RIGHT), want)
    with pytest.raises(AttributeError, match="fixed when it is made"):
        c.num_disparities = 32


@pytest.mark.parametrize("cls", [sd.StereoMatcher, sd.SemiGlobalMatcher])
def test_isa_request_travels_not_the_isa_run(cls: Any) -> None:
    """ "auto" stays "auto" (the receiving machine picks its own kernels); an explicit request
    stays explicit."""
    assert pickle.loads(pickle.dumps(cls(num_disparities=16)))._isa_arg == "auto"
    assert pickle.loads(pickle.dumps(cls(num_disparities=16, isa="baseline"))).isa == "baseline"


def rectifier() -> sd.StereoRectifier:
    K = np.array([[80.0, 0, 30], [0, 80, 18], [0, 0, 1]])
    D = np.array([0.05, -0.01, 0.001, 0.0, 0.0])
    c, s = np.cos(0.02), np.sin(0.02)
    R = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return sd.StereoRectifier(
        K1=K, D1=D, K2=K, D2=D, R=R, T=[-0.1, 0.002, 0], image_size=(61, 37), threads=2
    )


@pytest.mark.parametrize("clone", [lambda r: pickle.loads(pickle.dumps(r)), copy.deepcopy])
def test_rectifier_round_trip(clone: Any) -> None:
    r = rectifier()
    grey16 = (LEFT[..., 0].astype(np.uint16) * 257, RIGHT[..., 0].astype(np.uint16) * 257)
    want = [r.rectify(LEFT, RIGHT), r.rectify(*grey16)]
    c = clone(r)
    for name in ("R1", "R2", "P1", "P2", "Q", "roi1", "roi2", "image_size", "output_size"):
        np.testing.assert_array_equal(getattr(c, name), getattr(r, name))
    for side in ("left", "right"):
        for a, b in zip(c.maps(side), r.maps(side), strict=True):
            np.testing.assert_array_equal(a, b)
    # Its remap tables are built again, its own (both precisions, the 16-bit one on demand).
    got = [c.rectify(LEFT, RIGHT), c.rectify(*grey16)]
    for g, w in zip(got, want, strict=True):
        same_output(g, w)
    for precision in ("fixed", "float"):
        if precision in r._tables:
            assert all(
                isinstance(t, _core.RemapTable) and t is not u
                for t, u in zip(c._table_pair(precision), r._tables[precision], strict=True)
            )


def match_there(matcher: Any, left: np.ndarray, right: np.ndarray) -> Any:
    return matcher.compute(left, right)


def test_matchers_run_in_a_spawned_process() -> None:
    """What a process pool (or a Dask worker) does: the matcher and the pair sent to a new
    interpreter, the result sent back."""
    matchers = [sd.StereoMatcher(num_disparities=16), sd.SemiGlobalMatcher(num_disparities=16)]
    ctx = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:
        futures = [pool.submit(match_there, m, LEFT, RIGHT) for m in matchers]
        for m, f in zip(matchers, futures, strict=True):
            same_output(f.result(timeout=120), m.compute(LEFT, RIGHT))
