"""Stores of this checkout against those of another commit, byte for byte (run by hand).

    python bench/same_stores.py [--ref HEAD~1] [--surface smooth] [--files ../shared/data/*.laz ...]

A refactoring must leave every store as it was.  This checks out ``--ref``
into a temporary worktree, runs ``terrain run`` of both versions on the demo
survey and on each real sample with ground (default layers plus slope, face
kind and point count; the samples at 1 unit and 100-unit tiles, so that each
is several tiles), and compares every array and every chunk file
(``--changed dsm,chm``: but those, changed on purpose; the demo writes them).  Each
version compiles its own kernels in a cache folder of its own.  With
``--surface smooth`` the samples are run with the smooth surface (a change of
its kernels that should change no number).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
SHARED = HERE.parent / "shared" / "data"
SAMPLES = ["ign_semis_lambert93.laz", "extra_byte_blocks_lambert93.laz", "autzen_trim.las", "startinpy_small_extrabytes.laz",
           "4_6_crop_us_feet.las"]


def _terrain(source: Path, args: list[str], cache: Path) -> None:
    env = dict(os.environ, PYTHONPATH=str(source), NUMBA_CACHE_DIR=str(cache))
    done = subprocess.run([sys.executable, "-m", "pipeline.cli", *args, "-q"], env=env, capture_output=True, text=True,
                          cwd=source)
    if done.returncode:
        raise SystemExit(f"{source}: terrain {' '.join(args)} failed:\n{done.stderr[-2000:]}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--ref", default="HEAD~1", help="the commit to compare with")
    parser.add_argument("--files", nargs="*", type=Path, default=[SHARED / name for name in SAMPLES])
    parser.add_argument("--surface", default="linear", choices=("linear", "smooth"), help="the samples' surface")
    parser.add_argument("--changed", default="", help="arrays changed on purpose, left out (comma-separated: dsm,chm)")
    args = parser.parse_args()
    sys.path.insert(0, str(HERE))
    from tests.pipeline.store_checks import assert_same_store

    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        old = tmp_path / "ref"
        subprocess.run(["git", "-C", str(HERE), "worktree", "add", "--detach", str(old), args.ref], check=True,
                       capture_output=True)
        try:
            jobs = [("demo", None)] + [(f.name, f) for f in args.files if f.exists()]
            rows = []
            for name, path in jobs:
                stores = []
                for label, source in (("ref", old), ("now", HERE)):
                    out = tmp_path / f"{label}_{name}"
                    if path is None:
                        _terrain(source, ["demo", "--out", str(out)], tmp_path / f"cache_{label}")
                        stores.append(out / "dem.zarr")
                    else:
                        _terrain(source, ["run", str(path), "-o", str(out / "dem.zarr"), "--resolution", "1",
                                          "--tile-size", "100", "--layers", "slope,face_kind,point_count",
                                          "--surface", args.surface],
                                 tmp_path / f"cache_{label}")
                        stores.append(out / "dem.zarr")
                changed = tuple(n for n in args.changed.split(",") if n)
                assert_same_store(stores[1], stores[0], changed)
                rows.append(name)
                but = f" but {', '.join(changed)}" if changed else ""
                print(f"{name}: the same store{but}, byte for byte", flush=True)
        finally:
            subprocess.run(["git", "-C", str(HERE), "worktree", "remove", "--force", str(old)], capture_output=True)
    print(f"\n{len(rows)} store(s) identical to {args.ref}'s")


if __name__ == "__main__":
    main()
