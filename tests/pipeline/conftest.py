"""Fixtures shared by the pipeline tests."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="module")
def server():
    """A real S3 server (moto's ``moto_server``) on 127.0.0.1, one per test module."""
    pytest.importorskip("moto")
    from .s3server import start_s3_server

    s3 = start_s3_server()
    yield s3
    s3.stop()
