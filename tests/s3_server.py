"""A real S3-compatible server on 127.0.0.1 for the store tests: moto's server mode.

It speaks the S3 REST protocol over HTTP like MinIO or AWS, so the service's boto3 client
talks to it exactly as in production (signatures, multipart uploads, ranges, errors); it
holds its objects in memory and needs nothing but ``pip install 'moto[server]'``.
"""

from __future__ import annotations

import uuid
from typing import Any

# the standard variables the service reads (any non-empty credentials: moto checks none)
CREDENTIALS = {"AWS_ACCESS_KEY_ID": "scanplan-test", "AWS_SECRET_ACCESS_KEY": "scanplan-test",
               "AWS_DEFAULT_REGION": "us-east-1"}


class S3Server:
    """``moto.server.ThreadedMotoServer`` on a free port of 127.0.0.1."""

    def __init__(self) -> None:
        from moto.server import ThreadedMotoServer

        self._server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
        self._server.start()
        host, port = self._server.get_host_and_port()
        self.endpoint = f"http://{host}:{port}"
        self._client: Any = None

    def env(self) -> dict[str, str]:
        """The environment of a process that should use this server."""
        return {"AWS_ENDPOINT_URL": self.endpoint, **CREDENTIALS}

    def client(self) -> Any:
        """A boto3 client of this server (made once: a client costs some 0.3 s to build)."""
        if self._client is None:
            self._client = self._new_client()
        return self._client

    def _new_client(self) -> Any:
        import boto3

        return boto3.client("s3", endpoint_url=self.endpoint,
                            aws_access_key_id=CREDENTIALS["AWS_ACCESS_KEY_ID"],
                            aws_secret_access_key=CREDENTIALS["AWS_SECRET_ACCESS_KEY"],
                            region_name=CREDENTIALS["AWS_DEFAULT_REGION"])

    def new_bucket(self) -> str:
        """A bucket of its own for one test."""
        name = f"scanplan-{uuid.uuid4().hex[:16]}"
        self.client().create_bucket(Bucket=name)
        return name

    def keys(self, bucket: str, prefix: str = "") -> list[str]:
        """Every key in ``bucket`` below ``prefix``, sorted."""
        pages = self.client().get_paginator("list_objects_v2").paginate(Bucket=bucket,
                                                                          Prefix=prefix)
        return sorted(item["Key"] for page in pages for item in page.get("Contents", []))

    def stop(self) -> None:
        self._server.stop()
