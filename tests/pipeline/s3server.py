"""A real S3 protocol server for the tests: moto's ``moto_server`` on 127.0.0.1."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

BIN = Path(sys.executable).parent


@dataclass
class S3Server:
    process: subprocess.Popen
    endpoint: str
    key: str
    secret: str

    def env(self, **more: str) -> dict[str, str]:
        """The environment of a process that uses this server (as s3fs and botocore read it)."""
        env = {k: v for k, v in os.environ.items() if not k.startswith("AWS_")}
        env.update(AWS_ACCESS_KEY_ID=self.key, AWS_SECRET_ACCESS_KEY=self.secret, AWS_ENDPOINT_URL=self.endpoint,
                   AWS_DEFAULT_REGION="us-east-1")
        env.update(more)
        return env

    def filesystem(self, **options):
        import s3fs

        return s3fs.S3FileSystem(key=self.key, secret=self.secret, endpoint_url=self.endpoint,
                                 skip_instance_cache=True, **options)

    def stop(self) -> None:
        self.process.terminate()
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_s3_server(authenticated: bool = False) -> S3Server:
    """Start ``moto_server``; with ``authenticated`` it checks every request's
    credentials, and only the returned key and secret are valid."""
    port = _free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("AWS_")}
    if authenticated:
        env["INITIAL_NO_AUTH_ACTION_COUNT"] = "3"  # the three IAM calls below make the one valid key
    process = subprocess.Popen([str(BIN / "moto_server"), "-H", "127.0.0.1", "-p", str(port)], env=env,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 30
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            break
        except OSError:
            if time.time() > deadline or process.poll() is not None:
                process.kill()
                raise RuntimeError("moto_server did not start")
            time.sleep(0.2)
    endpoint = f"http://127.0.0.1:{port}"
    key, secret = "testing-key", "testing-secret"
    if authenticated:
        import boto3

        iam = boto3.client("iam", endpoint_url=endpoint, region_name="us-east-1",
                           aws_access_key_id="bootstrap", aws_secret_access_key="bootstrap")
        iam.create_user(UserName="terrain")
        made = iam.create_access_key(UserName="terrain")["AccessKey"]
        policy = {"Version": "2012-10-17", "Statement": [{"Effect": "Allow", "Action": "*", "Resource": "*"}]}
        iam.put_user_policy(UserName="terrain", PolicyName="all", PolicyDocument=json.dumps(policy))
        key, secret = made["AccessKeyId"], made["SecretAccessKey"]
    return S3Server(process, endpoint, key, secret)
