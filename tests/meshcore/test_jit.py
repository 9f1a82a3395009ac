"""Kernels compile once per argument types, and sort keys keep the floats' order."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest

from meshcore import _jit
from meshcore._order import order_ties_by, sortable_keys


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    """An empty kernel cache of the test's own."""
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path))
    return tmp_path


def _kernel(function):
    """Compiled as meshcore's kernels are, but not cached (a kernel loaded
    from the cache would not compile the helpers it calls)."""
    return _jit._Dispatcher(py_func=function, locals={}, targetoptions={"nopython": True})


def _add(a, k):
    return a + k


_add = _kernel(_add)


def _add_a_constant(a):
    return _add(a, 1)


def _add_a_variable(a, k):
    return _add(a, k)


_add_a_constant = _kernel(_add_a_constant)
_add_a_variable = _kernel(_add_a_variable)


@pytest.mark.skipif(numba.config.DISABLE_JIT, reason="kernels run as Python")
def test_a_helper_called_with_a_constant_and_with_a_variable_is_compiled_once():
    assert _add_a_constant(2) == 3 and _add_a_variable(2, 5) == 7
    assert _add.as_helper().signatures == [(numba.int64, numba.int64)]


def _sum_of(a, k):
    return a + k


_sum_of = _kernel(_sum_of)


def _sum_of_elements(small, wide):
    return _sum_of(small[0], wide[0]) + _sum_of(wide[0], small[0]) + _sum_of(small[0], small[0])


_sum_of_elements = _kernel(_sum_of_elements)


@pytest.mark.skipif(numba.config.DISABLE_JIT, reason="kernels run as Python")
def test_a_helper_passed_narrower_signed_integers_is_compiled_once_for_int64():
    small = np.array([-2_000_000_000], dtype=np.int32)  # twice this overflows an int32
    assert _sum_of_elements(small, np.array([5], dtype=np.int64)) == 2 * (5 - 2_000_000_000) - 4_000_000_000
    assert _sum_of.as_helper().signatures == [(numba.int64, numba.int64)]


def test_sortable_keys_order_and_equality_are_the_floats():
    rng = np.random.default_rng(5)
    values = np.concatenate([rng.normal(size=200) * 10.0 ** rng.integers(-300, 300, 200),
                             [0.0, -0.0, 0.0, np.inf, -np.inf, 5e-324, -5e-324, 1.0, 1.0]])
    keys = sortable_keys(values)
    assert keys.dtype == np.uint64
    np.testing.assert_array_equal(keys[:, None] < keys[None, :], values[:, None] < values[None, :])
    np.testing.assert_array_equal(keys[:, None] == keys[None, :], values[:, None] == values[None, :])


def test_order_ties_by_sorts_each_run_of_equal_keys_by_its_ties():
    rng = np.random.default_rng(8)
    key = np.sort(rng.integers(0, 5, 300)).astype(np.uint64)  # long runs: the merge sort
    tie = sortable_keys(rng.normal(size=300))
    order = np.arange(300)
    expected = np.lexsort((tie, key))
    order_ties_by(order, key.copy(), tie.copy())
    np.testing.assert_array_equal(order, expected)


def test_order_ties_by_keeps_equal_ties_in_their_order_in_long_runs():
    rng = np.random.default_rng(9)
    for n in (33, 64, 65, 1000):  # runs past the insertion sort's 32, of lengths round and odd
        key = np.sort(rng.integers(0, 2, n)).astype(np.uint64)
        tie = rng.integers(0, 4, n).astype(np.uint64)  # many equal ties: the merge must be stable
        order = rng.permutation(n)
        by = np.lexsort((tie, key))  # lexsort is stable
        expected_order, expected_tie = order[by], tie[by]
        order_ties_by(order, key, tie)
        np.testing.assert_array_equal(order, expected_order)
        np.testing.assert_array_equal(tie, expected_tie)


@pytest.mark.skipif(numba.config.DISABLE_JIT, reason="kernels run as Python")
def test_compiled_on_disk_tells_whether_the_cache_holds_a_kernel(fresh_cache):

    def _twice(a):
        return 2 * a

    kernel = _jit.njit(_twice)
    assert not _jit.compiled_on_disk(kernel)
    assert kernel(4) == 8
    assert _jit.compiled_on_disk(kernel) and any(fresh_cache.rglob("*.nbi"))


def _scaled(a, k):
    if k == 0.0:
        raise ValueError("a helper's error reaches Python")
    return a * k


def _sum_scaled(values, k):
    total = 0.0
    for v in values:
        total += _scaled_helper(v, k)  # noqa: F821 - set by the test
    return total


def _largest_scaled(values, k):
    best = -np.inf
    for v in values:
        best = max(best, _scaled_helper(v, k))  # noqa: F821 - set by the test
    return best


def _calling(monkeypatch, name: str, callee, caller):
    """``caller`` compiled as a kernel, calling ``callee`` by ``name``."""
    monkeypatch.setitem(globals(), name, callee)
    return _jit.njit(caller)


@pytest.mark.skipif(numba.config.DISABLE_JIT, reason="kernels run as Python")
def test_a_helper_runs_inside_kernels_and_refuses_calls_from_python(fresh_cache, monkeypatch):
    helper = _jit.njit_helper(_scaled)
    kernel = _calling(monkeypatch, "_scaled_helper", helper, _sum_scaled)
    assert kernel(np.array([1.0, 2.0, 3.0]), 2.0) == 12.0
    assert helper.signatures == [(numba.float64, numba.float64)]  # compiled, for the kernel
    assert isinstance(helper.overloads[(numba.float64, numba.float64)].library, _jit._HelperLibrary)
    # the same types from Python: no entry point to reach, an error instead of a crash
    with pytest.raises(TypeError, match="called only from kernels"):
        helper(1.0, 2.0)
    with pytest.raises(TypeError, match="called only from kernels"):
        helper(1, 2)
    assert _jit.compiled_on_disk(helper) and _jit.compiled_on_disk(kernel)
    # another process's dispatchers load both from the cache and still run
    fresh_helper = _jit.njit_helper(_scaled)
    fresh = _calling(monkeypatch, "_scaled_helper", fresh_helper, _sum_scaled)
    assert fresh(np.array([4.0]), 0.5) == 2.0
    assert fresh.stats.cache_hits and not fresh.stats.cache_misses
    # and a kernel of its own compiles with the helper as the cache holds it
    largest = _jit.njit(_largest_scaled)
    assert largest(np.array([1.0, -3.0, 2.5]), -2.0) == 6.0
    assert fresh_helper.stats.cache_hits and not fresh_helper.stats.cache_misses
    # read back as a module to link in, not compiled as it is into the process's
    # code, where it would stand in for the optimised copies the kernels link in
    cached = fresh_helper.overloads[(numba.float64, numba.float64)]
    assert isinstance(cached.library, _jit._HelperLibrary)
    assert not cached.library.codegen._engine.is_symbol_defined(cached.fndesc.mangled_name)
    with pytest.raises(ValueError, match="a helper's error reaches Python"):  # through its caller
        largest(np.array([1.0]), 0.0)


def _cubed(a):
    return a * a * a


def _cubes(values):
    out = np.empty_like(values)
    for i in range(values.shape[0]):
        out[i] = _cubed_kernel(values[i])  # noqa: F821 - set by the test
    return out


@pytest.mark.skipif(numba.config.DISABLE_JIT, reason="kernels run as Python")
def test_a_kernel_that_kernels_call_is_compiled_for_them_as_a_helper(fresh_cache, monkeypatch):
    cubed = _jit.njit(_cubed)
    cubes = _calling(monkeypatch, "_cubed_kernel", cubed, _cubes)
    np.testing.assert_array_equal(cubes(np.array([1.0, 2.0])), [1.0, 8.0])
    # its callers link in the helper's code: no entry point from Python was compiled
    assert cubed.signatures == [] and cubed.as_helper().signatures == [(numba.float64,)]
    assert isinstance(cubed.as_helper().overloads[(numba.float64,)].library, _jit._HelperLibrary)
    # Python's first call compiles the kernel itself, cached in files of its own
    assert cubed(3.0) == 27.0 and cubed.signatures == [(numba.float64,)]
    assert _jit.compiled_on_disk(cubed) and _jit.compiled_on_disk(cubed.as_helper())
    assert len({p.name.split(".")[-2] for p in fresh_cache.rglob("*_cubed*.nbi")}) == 2
    # a kernel compiled after that links in the kernel's own code
    again = _jit.njit(_cubes)
    np.testing.assert_array_equal(again(np.array([2.0])), [8.0])
    assert again.stats.cache_hits  # from the cache: the same code either way
    # another process: the caller and its helper come from the cache
    fresh = _jit.njit(_cubed)
    fresh_cubes = _calling(monkeypatch, "_cubed_kernel", fresh, _cubes)
    np.testing.assert_array_equal(fresh_cubes(np.array([-1.0, 3.0])), [-1.0, 27.0])
    assert fresh_cubes.stats.cache_hits and not fresh_cubes.stats.cache_misses
    assert fresh.signatures == []


def _scaled_sum(a, b):
    out = _jit.empty(a.size)
    for i in range(a.size):
        out[i] = 0.5 * a[i] + b[i]
    return out


@pytest.mark.skipif(numba.config.DISABLE_JIT, reason="kernels run as Python")
@pytest.mark.parametrize("wide", [True, False])
def test_kernels_of_some_modules_may_use_the_widest_vectors_with_the_same_results(fresh_cache, monkeypatch, wide):
    modules = _jit._WIDE_VECTOR_MODULES | {__name__} if wide else _jit._WIDE_VECTOR_MODULES - {__name__}
    monkeypatch.setattr(_jit, "_WIDE_VECTOR_MODULES", modules)
    helper = _jit.njit_helper(_cubed)
    cubes = _calling(monkeypatch, "_cubed_kernel", helper, _cubes)
    np.testing.assert_array_equal(cubes(np.array([2.0])), [8.0])
    scaled_sum = _jit.njit(_scaled_sum)
    a, b = np.random.default_rng(3).normal(size=(2, 1001))
    np.testing.assert_array_equal(scaled_sum(a, b), 0.5 * a + b)  # numpy's operations, bit for bit
    for code in (scaled_sum.inspect_llvm(scaled_sum.signatures[0]), cubes.inspect_llvm(cubes.signatures[0]),
                 str(helper.overloads[(numba.float64,)].library._final_module)):
        assert (_jit._WIDE_VECTORS in code) == wide


@pytest.mark.skipif(numba.config.DISABLE_JIT, reason="kernels run as Python")
def test_the_smooth_surfaces_kernels_prefer_the_widest_vectors(fresh_cache):
    from meshcore import kriging

    correlation = _kernel(kriging._correlation_kernel.py_func)  # compiled here, not read from the cache
    out = np.empty(3)
    correlation(np.array([0.5, 1.0, 2.0]), 1.0, 1, out)
    assert _jit._WIDE_VECTORS in correlation.inspect_llvm(correlation.signatures[0])


def _lane_steps(c, g, scale, count):
    # three rows of a (4, 3, LANES) array scaled, then rows of products subtracted from another's
    _jit.lanes_scale(c, _jit.LANES, 3 * _jit.LANES, scale, 0, count)
    _jit.lanes_subtract_products(g, 2 * _jit.LANES, _jit.LANES, c, 0, c, _jit.LANES, 3 * _jit.LANES, count)


def test_lane_operations_do_each_lanes_operations_as_numpy_does(fresh_cache):
    lanes = _jit.LANES
    rng = np.random.default_rng(8)
    c, g, scale = rng.normal(size=(4, 3, lanes)), rng.normal(size=(6, lanes)), rng.normal(size=lanes)
    expected_c, expected_g = c.copy(), g.copy()
    expected_c[:3, 1] *= scale
    expected_g[2:5] -= expected_c[0, 0] * expected_c[:3, 1]
    python_c, python_g = c.copy(), g.copy()  # as kernels running as Python do them
    _jit._lanes_scale(python_c, lanes, 3 * lanes, scale, 0, 3)
    _jit._lanes_subtract_products(python_g, 2 * lanes, lanes, python_c, 0, python_c, lanes, 3 * lanes, 3)
    compiled_c, compiled_g = c.copy(), g.copy()
    if not numba.config.DISABLE_JIT:
        _jit.njit(_lane_steps)(compiled_c, compiled_g, scale, 3)
    else:
        compiled_c, compiled_g = python_c, python_g
    for got_c, got_g in ((python_c, python_g), (compiled_c, compiled_g)):
        np.testing.assert_array_equal(got_c, expected_c)  # bit for bit
        np.testing.assert_array_equal(got_g, expected_g)
    untouched_c, untouched_g = c.copy(), g.copy()
    _jit.njit(_lane_steps)(untouched_c, untouched_g, scale, 0)  # no rows
    np.testing.assert_array_equal(untouched_c, c)
    np.testing.assert_array_equal(untouched_g, g)


def _new_arrays(n, like):
    a = _jit.empty(n, dtype=np.int32)
    for i in range(n):
        a[i] = 3 * i
    b = _jit.zeros((n, 3))
    c = _jit.full(n, -1, dtype=np.int64)
    d = _jit.full((2, n), True, dtype=np.bool_)
    e = _jit.empty_like(like)
    e[:] = like
    f = _jit.full(n, 0.5)
    return a, b, c, d, e, f


def test_arrays_created_in_kernels_are_numpys(fresh_cache):
    new_arrays = _jit.njit(_new_arrays)
    like = np.arange(6.0).reshape(2, 3)
    a, b, c, d, e, f = new_arrays(4, np.asfortranarray(like))
    np.testing.assert_array_equal(a, np.array([0, 3, 6, 9], dtype=np.int32))
    assert a.dtype == np.int32 and b.dtype == np.float64 and c.dtype == np.int64 and d.dtype == np.bool_
    np.testing.assert_array_equal(b, np.zeros((4, 3)))
    np.testing.assert_array_equal(c, np.full(4, -1))
    assert d.shape == (2, 4) and d.all()
    np.testing.assert_array_equal(e, like)
    assert e.flags.f_contiguous and e.dtype == like.dtype
    np.testing.assert_array_equal(f, np.full(4, 0.5))
    empties = new_arrays(0, like)
    assert [x.shape for x in empties] == [(0,), (0, 3), (0,), (2, 0), (2, 3), (0,)]


def _extremes(a, b):
    return _jit.smaller(a, b), _jit.larger(a, b)


@pytest.mark.parametrize(
    "a, b", [(1.0, 2.0), (2.0, 1.0), (-0.0, 0.0), (0.0, -0.0), (np.nan, 1.0), (1.0, np.nan), (3, 2.5), (-4, 7)]
)
def test_smaller_and_larger_in_kernels_are_min_and_max(fresh_cache, a, b):
    low, high = _jit.njit(_extremes)(a, b)
    for got, expected in ((low, min(a, b)), (high, max(a, b))):
        assert (got == expected and math.copysign(1.0, got) == math.copysign(1.0, expected)) or (
            math.isnan(got) and math.isnan(expected)
        )


def test_compiler_flags_hash_and_compare_as_numbas_own():
    from numba.core.compiler import Flags

    rng = np.random.default_rng(5)
    names = ["nrt", "no_cpython_wrapper", "boundscheck", "release_gil", "fastmath", "error_model", "no_cfunc_wrapper"]
    values = {"error_model": ["python", "numpy"]}
    made = []
    for _ in range(200):
        flags = Flags()
        for name in rng.choice(names, size=rng.integers(0, 4), replace=False):
            choices = values.get(str(name), [False, True])
            setattr(flags, str(name), choices[int(rng.integers(len(choices)))])
        made.append(flags)
    for a in made[:40]:
        for b in made:
            assert (a == b) == (a.values() == b.values())  # numba's definition
            assert a != b or hash(a) == hash(b)
        assert hash(a) == hash(tuple(sorted(a.values())))
