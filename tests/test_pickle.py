"""Matchers and rectifiers pickle and copy (for process pools and Dask workers): the copy has
the same parameters and ``isa`` request, native state of its own, and gives the same output."""

from __future__ import annotations

import concurrent.futures
import copy
import multiprocessing
import operator
import pickle
from typing import Any

import numpy as np
import pytest
from synthetic_pairs import shifted_pair

import stereodepth as sd
from stereodepth import _core
from stereodepth.calib.stereo import _rectified_calibration

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
        *(
            pytest.param(lambda m, p=p: pickle.loads(pickle.dumps(m, protocol=p)), id=f"pickle-{p}")
            for p in range(pickle.HIGHEST_PROTOCOL + 1)
        ),
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


class Fixed16(sd.SemiGlobalMatcher):
    """A subclass whose __init__ takes other arguments, with state of its own."""

    def __init__(self, name: str, **kw: Any) -> None:
        super().__init__(num_disparities=16, **kw)
        self._name = name


class Scaled(sd.StereoMatcher):
    """A subclass with slots of its own and params that add a key."""

    __slots__ = ("_scale",)

    def __init__(self, nd: int, scale: int = 2) -> None:
        super().__init__(num_disparities=nd)
        self._scale = scale

    @property
    def params(self) -> dict[str, Any]:
        return {**super().params, "scale": self._scale}


@pytest.mark.parametrize(
    "clone",
    [lambda m: pickle.loads(pickle.dumps(m)), copy.copy, copy.deepcopy],
    ids=["pickle", "copy", "deepcopy"],
)
def test_subclass_round_trip(clone: Any) -> None:
    """A subclass's copy is made without its __init__ and keeps its own attributes."""
    a = Fixed16("left", paths=4)
    b = Scaled(24, scale=5)
    ca, cb = clone(a), clone(b)
    assert type(ca) is Fixed16 and type(cb) is Scaled
    assert ca._name == "left" and cb._scale == 5
    assert ca.params == a.params and cb.params == b.params
    assert ca._native is not a._native and cb._native is not b._native
    same_output(ca.compute(LEFT, RIGHT), a.compute(LEFT, RIGHT))
    same_output(cb.compute(LEFT, RIGHT), b.compute(LEFT, RIGHT))


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
    # Its remap tables are built again, its own.
    assert c._tables == {}
    got = [c.rectify(LEFT, RIGHT), c.rectify(*grey16)]
    for g, w in zip(got, want, strict=True):
        same_output(g, w)
    assert c._tables.keys() == r._tables.keys()
    for precision, tables in r._tables.items():
        for t, u in zip(c._tables[precision], tables, strict=True):
            assert isinstance(t, _core.RemapTable) and t is not u


def test_rectifier_shallow_copy_shares_the_tables() -> None:
    r = rectifier()
    want = r.rectify(LEFT, RIGHT)
    c = copy.copy(r)
    assert c._tables is not r._tables
    assert all(c._tables[k] is r._tables[k] for k in r._tables)  # read only: shared
    same_output(c.rectify(LEFT, RIGHT), want)
    c.rectify(LEFT[..., 0].astype(np.uint16), RIGHT[..., 0].astype(np.uint16))
    assert set(c._tables) - set(r._tables)  # a precision built for the copy only


@pytest.mark.parametrize("clone", [lambda r: pickle.loads(pickle.dumps(r)), copy.copy])
def test_rectified_calibration_round_trip(clone: Any) -> None:
    """The identity case (a calibration already rectified) has no tables to drop."""
    K = np.array([[80.0, 0, 30], [0, 80, 18], [0, 0, 1]])
    calib = _rectified_calibration(K, K, 0.1, (61, 37), "test")
    r = sd.StereoRectifier.from_calibration(calib)
    c = clone(r)
    same_output(c.rectify(LEFT, RIGHT), r.rectify(LEFT, RIGHT))
    np.testing.assert_array_equal(c.Q, r.Q)


def test_matchers_and_rectifier_run_in_a_spawned_process() -> None:
    """What a process pool (or a Dask worker) does: the object and the pair sent to a new
    interpreter, the result sent back. (The callables sent are the standard library's: the
    child cannot import this test module.)"""
    matchers = [
        sd.StereoMatcher(num_disparities=16),
        sd.SemiGlobalMatcher(num_disparities=16, paths=8),
    ]
    r = rectifier()
    ctx = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:
        match = operator.methodcaller("compute", LEFT, RIGHT)
        futures = [pool.submit(match, m) for m in matchers]
        rectified = pool.submit(operator.methodcaller("rectify", LEFT, RIGHT), r)
        for m, f in zip(matchers, futures, strict=True):
            same_output(f.result(timeout=120), m.compute(LEFT, RIGHT))
        same_output(rectified.result(timeout=120), r.rectify(LEFT, RIGHT))
