"""Cached kernels follow the sources they were compiled from."""

from __future__ import annotations

from pathlib import Path

from meshcore import _jit
from meshcore.quality import s1_kernel


def test_kernels_compiled_from_other_sources_are_dropped(tmp_path):
    stale = [tmp_path / "flip._flip_kernel-60.py311.nbi", tmp_path / "flip._flip_kernel-60.py311.1.nbc"]
    for path in stale:
        path.write_bytes(b"old machine code")
    (tmp_path / _jit.SOURCES_STAMP).write_text("a digest of other sources")
    other = tmp_path / "notes.txt"
    other.write_text("kept")
    _jit.drop_stale_kernels([tmp_path])
    assert not any(p.exists() for p in stale) and other.exists()
    assert (tmp_path / _jit.SOURCES_STAMP).read_text() == _jit.sources_digest()
    # built from these sources: kept
    fresh = tmp_path / "quality.s1_kernel-80.py311.nbi"
    fresh.write_bytes(b"current machine code")
    _jit.drop_stale_kernels([tmp_path])
    assert fresh.exists()


def test_the_cache_folders_are_those_numba_uses():
    assert Path(s1_kernel._cache._cache_path) in _jit.kernel_cache_folders()


def test_a_kernels_cache_is_stamped_with_every_source_of_the_package():
    """A kernel inlines code of other modules (flips call the quality
    measures): its cache is valid only for the sources of the whole package,
    so an edit anywhere in it recompiles, and importing deletes nothing."""
    locator = s1_kernel._cache._impl.locator
    assert isinstance(locator, _jit._PackageStamp)
    own, package = locator.get_source_stamp()
    assert package == _jit.sources_digest()


_PROBE = """
import json, sys
from numba.core import event
compiled = []
class Count(event.Listener):
    def on_start(self, ev): compiled.append(ev.data["dispatcher"].py_func.__name__)
    def on_end(self, ev): pass
event.register("numba:compile", Count())
from meshcore.quality import s1_kernel
value = s1_kernel(0.0, 0.0, 1.0, 0.0, 0.0, 1.0)
print(json.dumps({"compiled": compiled, "cache": s1_kernel._cache._cache_path, "value": value}))
"""


def test_a_read_only_install_keeps_its_kernels_in_the_users_cache(tmp_path):
    """Where the package's folder takes no cache files (a system install, a
    container image), kernels are cached in the user's cache folder: the
    second process compiles nothing."""
    import json
    import os
    import shutil
    import subprocess
    import sys

    package = tmp_path / "site" / "meshcore"
    shutil.copytree(Path(_jit.__file__).parent, package, ignore=shutil.ignore_patterns("__pycache__"))
    (package / "__pycache__").write_text("not a folder: nothing can be written here")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_CACHE", "XDG_CACHE"))}
    env.update(PYTHONPATH=str(tmp_path / "site"), HOME=str(tmp_path / "home"), PYTHONDONTWRITEBYTECODE="1")
    runs = []
    for _ in range(2):
        done = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, cwd=tmp_path)
        assert done.returncode == 0, done.stderr[-2000:]
        runs.append(json.loads(done.stdout.strip().splitlines()[-1]))
    assert "s1_kernel" in runs[0]["compiled"] and runs[1]["compiled"] == []
    assert runs[0]["cache"].startswith(str(tmp_path / "home")) and runs[0]["value"] == runs[1]["value"]


def test_the_first_kernel_call_does_not_import_scipy_linalg():
    import importlib.util
    import subprocess
    import sys

    script = (
        "import sys, numpy as np, meshcore\n"
        "assert 'numba.np.arraymath' not in sys.modules, 'imported with the package, not at the first call'\n"
        "meshcore.convex_hull(np.arange(100.0), np.arange(100.0) % 7)\n"
        "import numba.np.arraymath as am, numba.np.linalg as la\n"
        "print('scipy.linalg' in sys.modules, am._HAVE_BLAS, la.ensure_blas.__module__)\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    scipy_linalg_imported, have_blas, ensure_blas_module = done.stdout.split()
    assert scipy_linalg_imported == "False"
    # numba's answer is the one its own check gives: is SciPy installed?
    assert have_blas == str(importlib.util.find_spec("scipy") is not None)
    assert ensure_blas_module == "numba.np.linalg"  # numba's own check is back for kernels that use a BLAS


_TYPED = '''
from typing import NamedTuple
import numpy as np
from meshcore.kernels import kernel


class {name}(NamedTuple):
    values: np.ndarray


@kernel
def total(room):
    return room.values.sum()
'''


def test_a_cache_naming_a_type_the_sources_no_longer_have_is_compiled_anew(tmp_path):
    """A kernel's cache index holds its signatures, with the types of its
    arguments: after an upgrade that renamed one (a named tuple), numba
    raised while unpickling the old index; it is stale, and the kernel compiles."""
    import os
    import subprocess
    import sys

    call = "import sys, numpy as np; sys.path.insert(0, sys.argv[1]); import typed; print(typed.total(typed.{name}(np.ones(3))))"
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    for name in ("Room", "Space"):  # the same kernel, on the same line, its argument's type renamed
        (tmp_path / "typed.py").write_text(_TYPED.format(name=name))
        done = subprocess.run([sys.executable, "-c", call.format(name=name), str(tmp_path)], capture_output=True,
                              text=True, env=env, timeout=120)
        assert done.returncode == 0, done.stderr[-500:]
        assert done.stdout.strip() == "3.0"
    assert list((tmp_path / "cache").rglob("*.nbi"))  # the kernel was cached (the first run wrote an index)
