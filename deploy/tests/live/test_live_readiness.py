"""Readiness follows the store: with the S3 server stopped, /healthz/ready turns 503
while /healthz/live stays 200 (why the liveness probe must not be /healthz/ready)."""

from __future__ import annotations

import time

import pytest

from outcomes import prerequisite
from processes import http_get


@pytest.mark.stops_s3
def test_ready_503_and_live_200_with_the_s3_server_stopped(moto, replicas):
    if moto is None:
        pytest.skip("no object storage")
    prerequisite(replicas["tessera-2"].url is not None, "starting tessera-2")
    moto.proc.stop()
    url = replicas["tessera-2"].url
    st = 0
    deadline = time.time() + 20
    while time.time() < deadline:
        st, _, _ = http_get(url + "/healthz/ready", timeout=5)
        if st == 503:
            break
        time.sleep(0.5)
    live, _, _ = http_get(url + "/healthz/live")
    assert st == 503 and live == 200, f"ready {st}, live {live}"
