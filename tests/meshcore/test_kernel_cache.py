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
