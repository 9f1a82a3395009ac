"""One place for the compiler settings of every kernel.

Kernels are compiled once and cached on disk (``cache=True``) and release the
GIL (``nogil=True``) so that dask threads run them in parallel.  ``fastmath``
stays off: the exact predicates rely on IEEE round-to-nearest arithmetic.
Helpers that only other kernels call are compiled without an entry point
from Python (:data:`njit_helper`).  Helpers called per element with the
caller's arrays that allocate nothing can be compiled without reference
counting either (:data:`njit_borrowing`), with scratch space on the stack
(:func:`stack_array`).
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib.abc
import importlib.util
import operator
import pickle
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import llvmlite.binding as llvm
import llvmlite.ir as llvmir
import numba
import numpy as np
from numba.core import caching, cgutils, compiler, sigutils, types
from numba.core.codegen import JITCodeLibrary
from numba.core.compiler_lock import require_global_compiler_lock
from numba.core.imputils import impl_ret_new_ref, lower_builtin
from numba.core.registry import CPUDispatcher
from numba.core.typing.npydecl import parse_dtype, parse_shape
from numba.cpython.builtins import do_minmax
from numba.extending import intrinsic, type_callable
from numba.np.arrayobj import _empty_nd_impl, _parse_shape

__all__ = [
    "njit", "njit_helper", "njit_borrowing", "kernel", "stack_array", "empty", "zeros", "full", "empty_like", "smaller",
    "larger", "index", "LANES", "lanes_scale", "lanes_subtract_products", "drop_stale_kernels", "compiled_on_disk",
]

_PACKAGE = Path(__file__).resolve().parent


@functools.cache
def _package_digest() -> str:
    return sources_digest()


class _PackageStamp:
    """A cache locator's stamp of a kernel's sources: its own file, as numba
    stamps it, and every source of this package.

    numba checks only the file a kernel is defined in, but the flip and merge
    kernels inline the quality measures of another module: after a ``git
    pull`` in an editable install they would keep running the old code.  With
    the package's digest in the stamp, a cache compiled from other sources
    is stale and compiled again, with nothing deleted when the package is
    imported.
    """

    @classmethod
    def from_function(cls, py_func, py_file):
        try:
            if Path(py_file).resolve().parent != _PACKAGE:
                return None
        except OSError:
            return None
        return super().from_function(py_func, py_file)  # type: ignore[misc]

    def get_source_stamp(self):
        return (super().get_source_stamp(), _package_digest())  # type: ignore[misc]


class _UserProvided(_PackageStamp, caching.UserProvidedCacheLocator):
    """``NUMBA_CACHE_DIR``, when set."""


class _InTree(_PackageStamp, caching.InTreeCacheLocator):
    """Beside the sources, when that folder is writable."""


class _UserWide(_PackageStamp, caching.UserWideCacheLocator):
    """The user's cache folder, for a read-only install (a system package, a container image)."""


if not any(issubclass(c, _PackageStamp) for c in caching.CacheImpl._locator_classes):
    caching.CacheImpl._locator_classes[:0] = [_UserProvided, _InTree, _UserWide]


def _scipy_installed() -> None:
    if importlib.util.find_spec("scipy") is None:
        raise ImportError("scipy is required for linear algebra")


class _ArrayFunctionsLoader(importlib.abc.Loader):
    """Runs numba's array functions module with a check for a BLAS that asks
    whether SciPy is installed instead of importing ``scipy.linalg``.

    numba imports that module at the first kernel call of a process, and there
    imports ``scipy.linalg`` only to learn whether ``np.dot`` has a BLAS at
    hand (0.2 s, as long as the rest of a one-file job's start-up); no kernel
    here calls a BLAS.  Whether SciPy is installed gives the same answer, and a
    kernel that does use one still imports it, as numba does, when it is
    compiled.
    """

    def __init__(self, loader: importlib.abc.Loader) -> None:
        self._loader = loader

    def __getattr__(self, name: str):
        return getattr(self._loader, name)

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module) -> None:
        from numba.np import linalg

        checked = linalg.ensure_blas
        linalg.ensure_blas = _scipy_installed
        try:
            self._loader.exec_module(module)  # type: ignore[attr-defined]
        finally:
            linalg.ensure_blas = checked


class _ArrayFunctionsFinder(importlib.abc.MetaPathFinder):
    """Finds numba's array functions module once, with :class:`_ArrayFunctionsLoader`.

    The module is still imported when numba first needs it (in whichever
    thread calls the first kernel), not when this package is.
    """

    name = "numba.np.arraymath"

    def find_spec(self, fullname, path, target=None):
        if fullname != self.name:
            return None
        with contextlib.suppress(ValueError):
            sys.meta_path.remove(self)
        spec = importlib.util.find_spec(fullname)
        if spec is not None and spec.loader is not None:
            spec.loader = _ArrayFunctionsLoader(spec.loader)
        return spec


if _ArrayFunctionsFinder.name not in sys.modules and not any(
    isinstance(finder, _ArrayFunctionsFinder) for finder in sys.meta_path
):
    sys.meta_path.insert(0, _ArrayFunctionsFinder())


def _speed_up_flags() -> None:
    """Hash and compare numba's compiler flags (``TargetConfig``) as numba
    does, faster.

    numba looks up every typed call of one of its own functions in a cache
    keyed by the compiler's flags.  Their hash is that of the options' names,
    the same for all flags, so every look-up compares flags, each time
    building two dictionaries of all 22 options' values: 8% of the kernels'
    compilation after the Delaunay sweep, under a profiler.  The same hash is
    now computed once per class, and flags with the same options set to the
    same values (nearly always) are equal without those dictionaries;
    otherwise numba's comparison decides.  Left as they are when numba
    hashes or compares flags otherwise.
    """
    from numba.core.compiler import Flags
    from numba.core.targetconfig import TargetConfig

    flags = Flags()
    if TargetConfig.__hash__ is _hash_of_flags or "__eq__" in vars(Flags):
        return
    if hash(flags) != hash(tuple(sorted(flags.values()))):
        return
    numbas_eq = TargetConfig.__eq__

    def eq(flags, other):
        if flags is other or (type(flags) is type(other) and flags._values == other._values):
            return True
        return numbas_eq(flags, other)

    TargetConfig.__eq__ = eq
    TargetConfig.__hash__ = _hash_of_flags


def _hash_of_flags(flags) -> int:
    return _hash_of_option_names(type(flags))


@functools.cache
def _hash_of_option_names(cls: type) -> int:
    return hash(tuple(sorted(cls.options)))


_speed_up_flags()


def _call_type(arg):
    """The type a kernel is compiled for when another kernel passes it ``arg``:
    not a constant's value, and a signed integer as ``int64``."""
    arg = types.unliteral(arg)
    if isinstance(arg, types.Integer) and arg.signed and arg.bitwidth < 64:
        return types.int64
    return arg


class _Dispatcher(CPUDispatcher):
    """A kernel that another kernel calls is compiled for its arguments'
    types, not for their constant values, and for ``int64`` where it is
    passed a narrower signed integer.

    numba types a constant argument of a call between kernels as a literal
    (``Literal[int](0)``), compiles the callee for it, and again for
    ``int64`` where a variable is passed: the Delaunay helpers alone were
    compiled twice or three times over, a quarter of the cold start.  The
    same went for an index read from an ``int32`` array beside a loop's
    ``int64`` one (``_add_triangle`` five times).  No kernel here dispatches
    on a constant's value or relies on an ``int32`` overflowing.

    A kernel that Python calls and other kernels call too (``orient2d``,
    ``_locate``, the quality measures) is, for those kernels, compiled as a
    helper (:meth:`as_helper`) unless this process compiled it for Python
    already: its callers link in its code and nothing more, and Python's
    entry point is compiled when Python first calls it.  Compiled as a kernel
    for its callers, it was optimised and turned into machine code once more,
    with its entry point, each time: a tenth of the Delaunay kernels'
    compilation.
    """

    _helper: _HelperDispatcher | None = None
    _cache_factory: Callable[[], Any] | None = None

    def __init__(self, py_func, locals=None, targetoptions=None, pipeline_class=None) -> None:
        super().__init__(py_func=py_func, locals=locals, targetoptions=targetoptions,
                         pipeline_class=pipeline_class or _KernelCompiler)

    @property
    def _cache(self):
        """numba's cache of this kernel, made when first asked for: finding
        its folder tests that folder for writing, 0.2 ms a kernel, and most
        of a process's kernels are helpers whose code their callers' caches
        hold (45 ms of every command's start)."""
        factory = self._cache_factory
        if factory is not None:
            self._cache_factory = None
            self.__dict__["_cache"] = factory()
        return self.__dict__["_cache"]

    @_cache.setter
    def _cache(self, cache) -> None:
        self._cache_factory = None
        self.__dict__["_cache"] = cache

    def get_call_template(self, args, kws):
        args = tuple(_call_type(a) for a in args)
        kws = {k: _call_type(v) for k, v in kws.items()}
        callee = self if kws or args in self.overloads else self.as_helper()
        return super(_Dispatcher, callee).get_call_template(args, kws)

    def get_overload(self, sig):
        """The compiled code a kernel's call links in: this kernel's, or its helper's."""
        args, _ = sigutils.normalize_signature(sig)
        if tuple(args) in self.overloads or self._helper is None:
            return super().get_overload(sig)
        return self._helper.get_overload(sig)

    def as_helper(self) -> _HelperDispatcher:
        """This kernel as other kernels call it, cached beside it."""
        if self._helper is None:
            options = {**self.targetoptions, "no_cpython_wrapper": True}
            helper = _HelperDispatcher(py_func=self.py_func, locals=self.locals, targetoptions=options)
            if self._cache_factory is not None or isinstance(self._cache, _FunctionCache):
                helper._cache_factory = functools.partial(_HelperCache, self.py_func, variant="-helper")
            self._helper = helper
        return self._helper


_WIDE_VECTORS = '"prefer-vector-width"="512"'
"""LLVM's function attribute that lets its vectoriser use 512-bit vectors."""

_WIDE_VECTOR_MODULES = frozenset({
    "meshcore.smooth", "meshcore.kriging", "meshcore.variogram", "meshcore.voids", "meshcore.cells", "meshcore._buckets",
})
"""The modules whose kernels prefer the widest vectors (:class:`_KernelLibrary`)."""


class _KernelLibrary(JITCodeLibrary):
    """The compiled code of a kernel; ``wide``: free to use the CPU's widest vectors.

    On a CPU with 512-bit vectors (AVX-512), LLVM vectorises loops 256 bits
    wide unless a function says it prefers wider ones.  The smooth surface's
    covariance loops ran 1.45 times faster 512 bits wide, its kriging 15%
    faster, so its kernels (:data:`_WIDE_VECTOR_MODULES`) say so.  The
    others, mostly scalar, gained nothing, and are compiled as before.
    Vectors of any width do the same IEEE operations on each element, so
    every result is the same; on other CPUs the attribute changes nothing.
    """

    wide = False

    def add_ir_module(self, ir_module) -> None:
        if self.wide:
            for function in ir_module.functions:
                if function.blocks:  # defined in this module, not declared
                    # llvmlite's add() takes only the attributes it names, not "key"="value" ones
                    set.add(function.attributes, _WIDE_VECTORS)
        super().add_ir_module(ir_module)


class _KernelCompiler(compiler.Compiler):
    """numba's compiler, with a :class:`_KernelLibrary` for the code."""

    library_class: type[_KernelLibrary] = _KernelLibrary

    def compile_extra(self, func):
        if self.state.library is None:
            library = self.library_class(self.state.targetctx.codegen(), func.__qualname__)
            library.wide = func.__module__ in _WIDE_VECTOR_MODULES
            library.enable_object_caching()
            self.state.library = library
        return super().compile_extra(func)


class _HelperLibrary(_KernelLibrary):
    """The compiled code of a helper: what its callers link in, and nothing more.

    numba optimises each compiled function's module as a whole and turns it
    into machine code, then does both again in every caller that links it
    in.  Only the callers' copies ever run, so a helper's module stops after
    its functions are optimised one by one (as every function is) and its own
    helpers are linked in: its callers optimise and compile it with
    themselves.  That was a seventh of the mesh kernels' compilation.  Its
    cache entry is that module (from which another process compiles the
    callers it needs), not machine code.
    """

    def finalize(self) -> None:
        require_global_compiler_lock()
        self._raise_if_finalized()
        linked = set()
        for library in self._linking_libraries:
            if library not in linked:
                linked.add(library)
                self._reload_init.update(library._reload_init)
                self._final_module.link_in(library._get_module_for_linking(), preserve=True)
        self._finalize_dynamic_globals()
        self._finalized = True

    def serialize_using_object_code(self):
        return self.serialize_using_bitcode()

    @classmethod
    def from_cache(cls, codegen, state) -> _HelperLibrary:
        """A helper's cache entry (:meth:`serialize_using_object_code`) read
        back as what its callers link in, and nothing more.

        numba reads a module from the cache into its JIT engine, where its
        functions are compiled to machine code as they are (not optimised)
        and, being defined there first, take the place of the optimised
        copies that kernels compiled later in the process link in: a kernel
        compiled beside a cached helper ran that helper four times slower.
        """
        name, kind, data = state
        if kind != "bitcode":
            raise ValueError(f"a helper's cache entry is a module's bitcode, not {kind!r}")
        library = cls(codegen, name)
        library._final_module = llvm.parse_bitcode(data)
        library._finalize_dynamic_globals()
        library._finalized = True
        return library

    @property
    def codegen(self):
        return _HelperCodegen(self._codegen)


class _HelperTarget:
    """numba's target context, as it rebuilds a helper from the cache: its
    module is read into a :class:`_HelperLibrary`."""

    def __init__(self, context) -> None:
        self._context = context

    def __getattr__(self, name: str):
        return getattr(self._context, name)

    def codegen(self) -> _HelperCodegen:
        return _HelperCodegen(self._context.codegen())


class _HelperCodegen:
    """numba's code generator, as it serves a helper: the address of the
    helper's environment (the Python objects its Python entry point would
    use) is not set, since neither its module nor that entry point is
    compiled to machine code; and a library is read back from the cache as
    :meth:`_HelperLibrary.from_cache`."""

    def __init__(self, codegen) -> None:
        self._codegen = codegen

    def __getattr__(self, name: str):
        return getattr(self._codegen, name)

    def set_env(self, env_name, env) -> None:
        pass

    def unserialize_library(self, state) -> _HelperLibrary:
        return _HelperLibrary.from_cache(self._codegen, state)


class _HelperResults(caching.CompileResultCacheImpl):
    """How a helper's compiled code is read from the cache (see :meth:`_HelperLibrary.from_cache`)."""

    def rebuild(self, target_context, payload):
        return super().rebuild(_HelperTarget(target_context), payload)._replace(target_context=target_context)


class _HelperCompiler(_KernelCompiler):
    """numba's compiler, with a :class:`_HelperLibrary` for the code."""

    library_class = _HelperLibrary


class _HelperDispatcher(_Dispatcher):
    """A kernel that only other kernels call: compiled without the wrapper
    that converts Python objects to its arguments and back, into a
    :class:`_HelperLibrary`.

    That wrapper is most of a small helper's code, and numba generates,
    optimises and compiles it to machine code for every helper of every
    kernel: about a fifth of a cold start.  Called from Python, such a helper
    raises instead of reaching code that is not there.
    """

    def __init__(self, py_func, locals, targetoptions) -> None:
        super().__init__(py_func=py_func, locals=locals, targetoptions=targetoptions, pipeline_class=_HelperCompiler)

    def add_overload(self, cres) -> None:
        self.overloads[tuple(cres.signature.args)] = cres  # not in the table Python calls dispatch on

    def _compile_for_args(self, *args, **kws):
        raise TypeError(f"{self.py_func.__qualname__} is called only from kernels (it has no entry point from Python)")

    def as_helper(self) -> _HelperDispatcher:
        return self


class _StaleProofIndex(caching.IndexDataCacheFile):
    """A kernel's cache index that reads as empty when it cannot be unpickled.

    An index holds the kernel's signatures, and a signature the types of its
    arguments: an index written by another version of this package can name
    a type this one no longer has (a named tuple renamed), and numba then
    raises while unpickling it, before it compares the sources' stamp that
    would have found the index stale.  Stale it is: the kernel compiles and
    the index is written anew.
    """

    def _load_index(self):
        try:
            return super()._load_index()
        except (AttributeError, ImportError, IndexError, TypeError, ValueError, EOFError, pickle.UnpicklingError):
            return {}


class _FunctionCache(caching.FunctionCache):
    """numba's cache of a kernel, with :class:`_StaleProofIndex`."""

    def __init__(self, py_func, variant: str = "") -> None:
        super().__init__(py_func)
        self._impl._filename_base += variant  # one kernel's variants in files of their own
        self._cache_file = _StaleProofIndex(cache_path=self._cache_path, filename_base=self._impl.filename_base,
                                            source_stamp=self._impl.locator.get_source_stamp())


class _HelperCache(_FunctionCache):
    """A helper's cache (:class:`_HelperResults`)."""

    _impl_class = _HelperResults


def _compiler(helper: bool = False, **options):
    """A decorator compiling with meshcore's settings (see the module's
    docstring) and ``options``; ``helper``: for calls from kernels only.

    No kernel is compiled with the wrapper that C code calls it through
    (numba's ``cfunc``): none is passed to C, or to another kernel as a
    first-class function.
    """
    targetoptions = {"nopython": True, "nogil": True, "error_model": "numpy", "no_cfunc_wrapper": True, **options}
    if helper:
        targetoptions["no_cpython_wrapper"] = True
    dispatcher_type = _HelperDispatcher if helper else _Dispatcher

    def compile_(function):
        if numba.config.DISABLE_JIT:
            return function
        dispatcher = dispatcher_type(py_func=function, locals={}, targetoptions=targetoptions)
        # numba's enable_caching(), with an index robust to old types
        dispatcher._cache_factory = functools.partial(_HelperCache if helper else _FunctionCache, function)
        return dispatcher

    return compile_


njit = _compiler()

#: for a helper that only other kernels call (:class:`_HelperDispatcher`)
njit_helper = _compiler(helper=True)


def kernel(function):
    """Compile ``function`` with meshcore's settings: cached on disk, the GIL
    released, numpy's error model (a division by zero gives inf or NaN).

    For the kernels of packages built on meshcore, so that every kernel of a
    run is compiled alike.
    """
    return njit(function)


#: for a helper that a kernel calls per element with its arrays, and that
#: creates none (scratch space: :func:`stack_array`): compiled without
#: reference counting.  Otherwise it takes and drops a reference to every
#: array it is given, two atomic operations each per call, which the compiler
#: cannot remove from a helper with loops and calls: a third of the Delaunay
#: sweep's time went there.
njit_borrowing = _compiler(helper=True, _nrt=False)


@intrinsic(prefer_literal=True)
def _stack_array(typingctx, count):
    """A float64 array of ``count`` (a literal) elements on the calling
    function's stack, uninitialised; valid until that function returns.

    Scratch space that needs no allocation, for helpers compiled with
    :data:`njit_borrowing` (which cannot allocate).
    """
    if not isinstance(count, types.IntegerLiteral):
        return None
    size = count.literal_value
    array_type = types.Array(types.float64, 1, "C")

    def codegen(context, builder, signature, args):
        data = cgutils.alloca_once(builder, context.get_value_type(types.float64), size=size)
        array = context.make_array(array_type)(context, builder)
        intp = context.get_value_type(types.intp)
        context.populate_array(
            array, data=data, shape=[intp(size)], strides=[intp(8)], itemsize=intp(8), meminfo=None
        )
        return array._getvalue()

    return array_type(count), codegen


def _heap_array(count: int) -> np.ndarray:
    return np.empty(count)


#: kernels running as Python (``NUMBA_DISABLE_JIT``) take their scratch from the heap
stack_array = _heap_array if numba.config.DISABLE_JIT else _stack_array


# New arrays in kernels.  numba compiles ``np.empty`` (and ``np.zeros``,
# ``np.full``, ``np.empty_like``) as a function of its own for every
# combination of shape and dtype a process meets, each a compilation of its
# own (50-70 ms), some twenty-five per part of a cold start: an eighth of the
# kernels after the Delaunay sweep.  These functions are numpy's when called
# from Python and, in a kernel, the same allocation written in place.


def empty(shape, dtype=np.float64) -> np.ndarray:
    """``np.empty(shape, dtype)``, in place in a kernel."""
    return np.empty(shape, dtype)


def zeros(shape, dtype=np.float64) -> np.ndarray:
    """``np.zeros(shape, dtype)``, in place in a kernel."""
    return np.zeros(shape, dtype)


def full(shape, value, dtype=np.float64) -> np.ndarray:
    """``np.full(shape, value, dtype)``, in place in a kernel."""
    return np.full(shape, value, dtype)


def empty_like(array: np.ndarray) -> np.ndarray:
    """``np.empty_like(array)``, in place in a kernel."""
    return np.empty_like(array)


def _new_array_type(shape, dtype) -> types.Array | None:
    element = types.float64 if dtype is None else parse_dtype(dtype)
    ndim = parse_shape(shape)
    if element is None or ndim is None:
        return None
    return types.Array(element, ndim, "C")


@type_callable(empty)
@type_callable(zeros)
def _type_new_array(context):
    def typer(shape, dtype=None):
        return _new_array_type(shape, dtype)

    return typer


@type_callable(full)
def _type_full(context):
    def typer(shape, value, dtype=None):
        if not isinstance(value, (types.Number, types.Boolean)):
            return None
        return _new_array_type(shape, dtype)

    return typer


@type_callable(empty_like)
def _type_empty_like(context):
    def typer(array):
        if isinstance(array, types.Array):
            return types.Array(array.dtype, array.ndim, "F" if array.layout == "F" else "C")
        return None

    return typer


def _new_array(context, builder, signature, args):
    """The new array of a call ``f(shape, ...)``, allocated as numba's ``np.empty`` allocates it."""
    shape = _parse_shape(context, builder, signature.args[0], args[0])
    return _empty_nd_impl(context, builder, signature.return_type, shape)


def _new_reference(context, builder, signature, array):
    return impl_ret_new_ref(context, builder, signature.return_type, array._getvalue())


@lower_builtin(empty, types.Any)
@lower_builtin(empty, types.Any, types.Any)
def _lower_empty(context, builder, signature, args):
    return _new_reference(context, builder, signature, _new_array(context, builder, signature, args))


@lower_builtin(zeros, types.Any)
@lower_builtin(zeros, types.Any, types.Any)
def _lower_zeros(context, builder, signature, args):
    array = _new_array(context, builder, signature, args)
    cgutils.memset(builder, array.data, builder.mul(array.itemsize, array.nitems), 0)
    return _new_reference(context, builder, signature, array)


@lower_builtin(full, types.Any, types.Any)
@lower_builtin(full, types.Any, types.Any, types.Any)
def _lower_full(context, builder, signature, args):
    array = _new_array(context, builder, signature, args)
    element = signature.return_type.dtype
    value = context.cast(builder, args[1], signature.args[1], element)
    value = context.get_value_as_data(builder, element, value)
    with cgutils.for_range(builder, array.nitems) as loop:
        builder.store(value, builder.gep(array.data, [loop.index]))
    return _new_reference(context, builder, signature, array)


@lower_builtin(empty_like, types.Array)
def _lower_empty_like(context, builder, signature, args):
    source = context.make_array(signature.args[0])(context, builder, value=args[0])
    array = _empty_nd_impl(context, builder, signature.return_type, cgutils.unpack_tuple(builder, source.shape))
    return _new_reference(context, builder, signature, array)


index = np.uint64
"""A value known to be >= 0 (a vertex or half-edge id read from an ``int32``
array, once checked against -1) as kernels index with it: ``x[index(a)]``.

numba gives a signed index Python's meaning (``a[-1]`` is the last element):
every load with one adds a test and a select.  In the kernels' loops over
corners and neighbours that cost 5-10% (the flip rounds, the sweep's
legalization, the merge candidates); an unsigned index has no such case.
The values, and so every result, are the same."""


# The smaller and the larger of numbers in kernels.  numba compiles ``min``
# and ``max`` as functions of their own for each combination of types, as it
# does ``np.empty``: some ten per compiling process.


def smaller(a, b):
    """``min(a, b)`` of two numbers, in place in a kernel: ``b`` if it is
    smaller, else ``a`` (a NaN ``a`` stays, as with ``min``)."""
    return min(a, b)


def larger(a, b):
    """``max(a, b)`` of two numbers, in place in a kernel."""
    return max(a, b)


@type_callable(smaller)
@type_callable(larger)
def _type_extreme(context):
    def typer(a, b):
        if isinstance(a, types.Number) and isinstance(b, types.Number):
            return context.unify_types(a, b)
        return None

    return typer


@lower_builtin(smaller, types.Number, types.Number)
def _lower_smaller(context, builder, signature, args):
    return do_minmax(context, builder, list(signature.args), list(args), operator.lt)


@lower_builtin(larger, types.Number, types.Number)
def _lower_larger(context, builder, signature, args):
    return do_minmax(context, builder, list(signature.args), list(args), operator.gt)


# Lanes: eight numbers side by side, as one vector.  Kernels that solve
# eight small systems at once keep each system's numbers in a lane (the last
# axis of their arrays, of length LANES); these operations do one step of all
# eight at once.  numba vectorises loops, not the eight statements of a loop
# over lanes that LLVM unrolls (its SLP vectoriser stays off), so such loops
# ran one number at a time.

LANES = 8
"""Numbers per lane operation: :func:`lanes_scale`, :func:`lanes_subtract_products`."""


# As Python, without numpy's warnings: lanes no system uses hold stale numbers
# (compiled, the same operations raise nothing either)


def _lanes_scale(out, at, step, scale, scale_at, count) -> None:
    flat = out.reshape(-1)
    by = scale.reshape(-1)[scale_at:scale_at + LANES].copy()
    with np.errstate(all="ignore"):
        for t in range(count):
            row = flat[at + t * step:at + t * step + LANES]
            row *= by


def _lanes_subtract_products(out, at, step, x, x_at, y, y_at, y_step, count) -> None:
    flat = out.reshape(-1)
    by = x.reshape(-1)[x_at:x_at + LANES].copy()
    ys = y.reshape(-1)
    with np.errstate(all="ignore"):
        for t in range(count):
            row = flat[at + t * step:at + t * step + LANES]
            row -= by * ys[y_at + t * y_step:y_at + t * y_step + LANES]


def _lanes_pointer(context, builder, array_type, array, at):
    """A pointer to the ``LANES`` numbers of ``array`` (C-contiguous) from flat index ``at`` on, as one vector."""
    data = context.make_array(array_type)(context, builder, array).data
    vector = llvmir.VectorType(llvmir.DoubleType(), LANES)
    return builder.bitcast(builder.gep(data, [at]), vector.as_pointer())


def _lanes_arguments(arrays: tuple, integers: tuple) -> bool:
    return all(isinstance(a, types.Array) and a.dtype == types.float64 and a.layout == "C" for a in arrays) and all(
        isinstance(i, types.Integer) for i in integers
    )


@intrinsic
def _lanes_scale_intrinsic(typingctx, out, at, step, scale, scale_at, count):
    if not _lanes_arguments((out, scale), (at, step, scale_at, count)):
        return None
    signature = types.void(out, types.intp, types.intp, scale, types.intp, types.intp)

    def codegen(context, builder, sig, args):
        out_v, at_v, step_v, scale_v, scale_at_v, count_v = args
        by = builder.load(_lanes_pointer(context, builder, sig.args[3], scale_v, scale_at_v), align=8)
        with cgutils.for_range(builder, count_v) as loop:
            where = _lanes_pointer(context, builder, sig.args[0], out_v, builder.add(at_v, builder.mul(loop.index, step_v)))
            builder.store(builder.fmul(builder.load(where, align=8), by), where, align=8)
        return context.get_dummy_value()

    return signature, codegen


@intrinsic
def _lanes_subtract_products_intrinsic(typingctx, out, at, step, x, x_at, y, y_at, y_step, count):
    if not _lanes_arguments((out, x, y), (at, step, x_at, y_at, y_step, count)):
        return None
    signature = types.void(out, types.intp, types.intp, x, types.intp, y, types.intp, types.intp, types.intp)

    def codegen(context, builder, sig, args):
        out_v, at_v, step_v, x_v, x_at_v, y_v, y_at_v, y_step_v, count_v = args
        by = builder.load(_lanes_pointer(context, builder, sig.args[3], x_v, x_at_v), align=8)
        with cgutils.for_range(builder, count_v) as loop:
            t = loop.index
            where = _lanes_pointer(context, builder, sig.args[0], out_v, builder.add(at_v, builder.mul(t, step_v)))
            ys = builder.load(_lanes_pointer(context, builder, sig.args[5], y_v, builder.add(y_at_v, builder.mul(t, y_step_v))),
                              align=8)
            builder.store(builder.fsub(builder.load(where, align=8), builder.fmul(by, ys)), where, align=8)
        return context.get_dummy_value()

    return signature, codegen


#: ``out[at + t * step + l] *= scale[scale_at + l]`` for ``t < count`` and
#: ``l < LANES``, indices into the C-contiguous float64 arrays as flat ones
#: (unchecked: they must lie inside)
lanes_scale = _lanes_scale if numba.config.DISABLE_JIT else _lanes_scale_intrinsic

#: ``out[at + t * step + l] -= x[x_at + l] * y[y_at + t * y_step + l]`` for
#: ``t < count`` and ``l < LANES``, as :data:`lanes_scale` indexes (``x``'s
#: lanes are read once, first)
lanes_subtract_products = _lanes_subtract_products if numba.config.DISABLE_JIT else _lanes_subtract_products_intrinsic


#: the name of the file, beside the cached kernels, that says which sources they were compiled from
SOURCES_STAMP = "meshcore-sources.sha256"


def drop_stale_kernels(folders: list[Path] | None = None) -> None:
    """Delete cached kernels compiled from other sources of this package (to
    reclaim their space: they are never loaded, see :class:`_PackageStamp`).

    ``folders`` defaults to the cache folders of the package's kernels.
    """
    digest = sources_digest()
    for folder in kernel_cache_folders() if folders is None else folders:
        stamp = folder / SOURCES_STAMP
        try:
            if stamp.read_text() == digest:
                continue
        except OSError:
            pass
        try:
            for stale in [*folder.glob("*.nbi"), *folder.glob("*.nbc")]:
                stale.unlink(missing_ok=True)
            folder.mkdir(parents=True, exist_ok=True)
            stamp.write_text(digest)
        except OSError:  # a read-only install: its files were all written together
            pass


def compiled_on_disk(kernel) -> bool:
    """Whether the cache holds ``kernel`` (a dispatcher of this package)
    compiled from these sources for this machine, for any argument types.
    ``True`` when that cannot be told (JIT disabled, no cache)."""
    cache = getattr(kernel, "_cache", None)
    try:
        index = cache._cache_file._load_index()  # empty when missing, or compiled from other sources
        magic = kernel.targetctx.codegen().magic_tuple()
    except Exception:  # noqa: BLE001 - numba's internals moved: do not guess
        return True
    return any(key[1] == magic for key in index)


def sources_digest() -> str:
    """SHA-256 of the package's Python sources."""
    here = Path(__file__).parent
    return hashlib.sha256(b"".join(p.read_bytes() for p in sorted(here.glob("*.py")))).hexdigest()


def kernel_cache_folders() -> list[Path]:
    """Where numba caches the kernels of the package's imported modules."""
    folders = set()
    for name, module in list(sys.modules.items()):
        if name.startswith(f"{__package__}.") and module is not None:
            for value in vars(module).values():
                cache = getattr(value, "_cache", None)
                if isinstance(value, numba.core.registry.CPUDispatcher) and hasattr(cache, "_cache_path"):
                    folders.add(Path(cache._cache_path))
    return sorted(folders)
