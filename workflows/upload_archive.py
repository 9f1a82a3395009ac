"""Copy a folder of LAS/LAZ files into a bucket, creating the bucket if needed.

    python upload_archive.py /data/archive s3://terrain/archive/

Files already there with the same size are left alone, so running it again
uploads only what is new.  Credentials and endpoint come from the
environment, as s3fs reads them.
"""

from __future__ import annotations

import sys
from pathlib import Path

import fsspec


def upload(folder: Path, url: str) -> int:
    fs, prefix = fsspec.core.url_to_fs(url)
    prefix = prefix.rstrip("/")
    bucket = prefix.split("/", 1)[0]
    if not fs.exists(bucket):
        fs.mkdir(bucket)
    sent = 0
    for path in sorted(folder.iterdir()):
        if path.suffix.lower() not in (".las", ".laz"):
            continue
        target = f"{prefix}/{path.name}"
        if fs.exists(target) and fs.size(target) == path.stat().st_size:
            continue
        fs.put_file(str(path), target)
        sent += 1
    return sent


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit("usage: upload_archive.py FOLDER s3://BUCKET/PREFIX/")
    count = upload(Path(sys.argv[1]), sys.argv[2])
    print(f"uploaded {count} file(s) to {sys.argv[2]}")
