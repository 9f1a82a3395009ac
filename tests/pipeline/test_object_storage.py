"""Archives and stores on object storage, against a real S3 server on loopback
(moto's ``moto_server``): a run from s3:// and http(s):// inputs into an s3://
store, errors that name the URL, and credentials that appear nowhere."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import xarray as xr

pytest.importorskip("s3fs")
pytest.importorskip("moto")

from pipeline.config import RunConfig  # noqa: E402
from pipeline.runs.runner import run  # noqa: E402
from pipeline.tools.synthetic import SurveySpec, write_survey  # noqa: E402

from .s3server import start_s3_server  # noqa: E402
from .store_checks import assert_same_store  # noqa: E402

TERRAIN = str(Path(sys.executable).parent / "terrain")
SECRET = "secret-that-must-not-leak-7f3a"


@pytest.fixture(scope="module")
def archive(server, tmp_path_factory):
    """A survey of two LAZ files in s3://archive/survey/, and its local copy."""
    local = tmp_path_factory.mktemp("archive")
    paths = write_survey(local / "survey", SurveySpec(points=40_000, files=2, width=240.0, height=160.0, seed=31))
    fs = server.filesystem()
    fs.mkdir("archive")
    for p in paths:
        fs.put_file(str(p), f"archive/survey/{p.name}")
    return local / "survey", [p.name for p in paths]


def _terrain(server, *args: str, env_more: dict | None = None, secret: str | None = None):
    env = server.env(**(env_more or {}))
    if secret is not None:
        env["AWS_SECRET_ACCESS_KEY"] = secret
    return subprocess.run([TERRAIN, *args], env=env, capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def reference(archive, tmp_path_factory) -> Path:
    """The same job over the local copy of the archive."""
    out = tmp_path_factory.mktemp("reference") / "local.zarr"
    run(RunConfig(inputs=(str(archive[0]),), output=str(out), resolution=1.0, tile_size=64.0, layers=("slope",),
                  workers=2), progress=False)
    return out


def test_a_run_from_s3_into_s3_equals_the_local_run_and_leaks_no_credential(server, archive, reference, tmp_path):
    names = archive[1]
    job_file = tmp_path / "job.toml"
    job_file.write_text(
        "[run]\n"
        'inputs = ["s3://archive/survey/"]\n'
        'output = "s3://archive/out/dem.zarr"\n'
        'resolution = 1.0\ntile_size = 64.0\nlayers = ["slope"]\nscratch_dir = "s3://archive/scratch/"\n'
        "[run.storage_options]\n"
        f'key = "{server.key}"\nsecret = "{SECRET}"\nendpoint_url = "{server.endpoint}"\n'
    )
    # moto without authentication takes any secret: this one is only in the job file
    job = _terrain(server, "run", "-v", "--log-json", "--config", str(job_file), "--no-progress", secret="unused")
    assert job.returncode == 0, job.stderr
    fs = server.filesystem()
    options = {"key": server.key, "secret": server.secret, "endpoint_url": server.endpoint}
    with xr.open_zarr("s3://archive/out/dem.zarr", storage_options=options) as ds:  # xarray reads it from s3
        assert ds.attrs["complete"] is True
        inputs = [i["path"] for i in ds.attrs["provenance"]["inputs"]]
        assert inputs == [f"s3://archive/survey/{n}" for n in names]
    assert not fs.find("archive/scratch/")  # the work files were on s3, and went with the run
    # the same bytes as a run over the same files on local disk
    fs.get("archive/out/dem.zarr", str(tmp_path / "fetched.zarr"), recursive=True)
    assert_same_store(tmp_path / "fetched.zarr", reference)
    item_text = fs.cat_file("archive/out/dem.stac.json").decode()
    item = json.loads(item_text)
    assert item["assets"]["zarr"]["href"] == "./dem.zarr" and item["properties"]["proj:code"] == "EPSG:2154"
    # the secret is in no log line, report, provenance or STAC item
    written = [job.stdout, job.stderr, item_text]
    written += [p.read_text(errors="replace") for p in (tmp_path / "fetched.zarr").rglob("*")
                if p.name in ("zarr.json", ".zattrs", ".zmetadata")]
    assert any('"provenance"' in text for text in written)
    for text in written:
        assert SECRET not in text and server.key not in text


def test_http_urls_and_globs_name_inputs(server, archive, reference, tmp_path):
    names = archive[1]
    # moto serves objects over plain HTTP GET with ranges, as a public bucket or a CDN does
    fs = server.filesystem()
    for name in names:
        fs.chmod(f"archive/survey/{name}", acl="public-read")
    urls = [f"{server.endpoint}/archive/survey/{name}" for name in names]
    job = _terrain(server, "run", *urls, "-o", str(tmp_path / "http.zarr"), "--resolution", "1", "--tile-size", "64",
                   "--layers", "slope", "--no-progress")
    assert job.returncode == 0, job.stderr
    assert_same_store(tmp_path / "http.zarr", reference)
    info = _terrain(server, "info", "s3://archive/**/*.laz", "--json")
    assert info.returncode == 0, info.stderr
    assert [f["path"] for f in json.loads(info.stdout)] == [f"s3://archive/survey/{n}" for n in names]


def test_errors_name_the_url_exit_2_and_leave_nothing_complete(server, archive, monkeypatch, capsys):
    from pipeline.cli import main

    for name, value in server.env().items():
        if name.startswith("AWS_"):
            monkeypatch.setenv(name, value)
    fs = server.filesystem()
    fs.pipe_file("archive/junk/notes.laz", b"PK\x03\x04" + b"\0" * 600)
    cases = [
        ("s3://no-such-bucket/survey/", "s3://archive/failed.zarr", "s3://no-such-bucket/survey/: no such bucket"),
        ("s3://archive/survey/missing.laz", "s3://archive/failed.zarr",
         "s3://archive/survey/missing.laz: no such object"),
        ("s3://archive/junk/notes.laz", "s3://archive/failed.zarr", "s3://archive/junk/notes.laz: not a LAS/LAZ file"),
        ("s3://archive/survey/", "s3://no-such-bucket/dem.zarr", "s3://no-such-bucket/dem.zarr: no such bucket"),
    ]
    for source, output, message in cases:
        code = main(["run", source, "-o", output, "--resolution", "1", "--no-progress", "-q"])
        lines = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(lines) == 1 and message in lines[0], (source, lines)
    assert not fs.exists("archive/failed.zarr")


def test_bad_credentials_are_refused_with_one_line_naming_the_url(archive, tmp_path):
    guarded = start_s3_server(authenticated=True)
    try:
        fs = guarded.filesystem()
        fs.mkdir("guarded")
        folder, names = archive
        fs.put_file(str(folder / names[0]), f"guarded/{names[0]}")
        job = _terrain(guarded, "run", f"s3://guarded/{names[0]}", "-o", str(tmp_path / "g.zarr"), "--resolution", "1",
                       "--no-progress", secret="not-the-secret")
        lines = job.stderr.strip().splitlines()
        assert job.returncode == 2 and len(lines) == 1, job.stderr
        assert lines[0].startswith(f"terrain: error: s3://guarded/{names[0]}: access denied"), job.stderr
        assert not (tmp_path / "g.zarr").exists()
        ok = _terrain(guarded, "info", f"s3://guarded/{names[0]}")  # the right key reads it
        assert ok.returncode == 0, ok.stderr
        # the job file's storage_options win over a wrong secret in the environment
        job_file = tmp_path / "job.toml"
        job_file.write_text(
            f'[run]\ninputs = ["s3://guarded/{names[0]}"]\noutput = "s3://guarded/dem.zarr"\nresolution = 1.0\n'
            f'[run.storage_options]\nkey = "{guarded.key}"\nsecret = "{guarded.secret}"\n'
        )
        job = _terrain(guarded, "run", "--config", str(job_file), "--no-progress", "-v", secret="not-the-secret")
        assert job.returncode == 0, job.stderr
        assert guarded.secret not in job.stdout + job.stderr
        assert guarded.secret not in fs.cat_file("guarded/dem.stac.json").decode()
    finally:
        guarded.stop()


def test_a_server_that_stops_mid_run_is_exit_1_and_the_run_goes_on_once_it_is_back(archive, reference, tmp_path):
    folder, names = archive
    s3 = start_s3_server()
    try:
        fs = s3.filesystem()
        fs.mkdir("flaky")
        for name in names:
            fs.put_file(str(folder / name), f"flaky/survey/{name}")
        command = [TERRAIN, "run", "s3://flaky/survey/", "-o", str(tmp_path / "dem.zarr"), "--resolution", "1",
                   "--tile-size", "64", "--layers", "slope", "--no-progress"]
        env = s3.env(AWS_MAX_ATTEMPTS="2")
        job = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for line in job.stderr:  # the headers are read: stop the server before the points are
            if "file(s), grid" in line:
                break
        s3.stop()
        rest = job.stderr.read()
        job.wait(timeout=120)
        errors = [line for line in rest.splitlines() if line.startswith("terrain: error:")]
        assert job.returncode == 1, rest
        assert len(errors) == 1 and "s3://flaky/survey/" in errors[0] and "stopped answering" in errors[0], rest
        assert not (tmp_path / "dem.zarr").exists() or not xr.open_zarr(tmp_path / "dem.zarr").attrs.get("complete")
    finally:
        s3.stop()
    back = start_s3_server()  # the same objects on a server that answers again
    try:
        fs = back.filesystem()
        fs.mkdir("flaky")
        for name in names:
            fs.put_file(str(folder / name), f"flaky/survey/{name}")
        again = subprocess.run(command, env=back.env(), capture_output=True, text=True, timeout=300)
        assert again.returncode == 0, again.stderr
    finally:
        back.stop()
    assert_same_store(tmp_path / "dem.zarr", reference)
