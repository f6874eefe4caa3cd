"""nginx.conf, run for real in front of the two replicas: pinned tiles cached (MISS then
HIT), unpinned ones and Range requests passed through, conditional requests reaching
the replicas, round robin, and every request still answered after one replica is
killed."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import time
from dataclasses import dataclass, field

import pytest

from commands import port_of
from deploy_paths import NGINX_CONF
from nginx_rules import local_nginx_conf
from outcomes import prerequisite
from processes import Proc, free_port, http_get


@dataclass
class Front:
    """What nginx answered, request by request, in the order the scenario sent them."""

    tail: str = ""
    up: bool = False
    dataset: tuple = (0, {}, b"")
    pinned: list = field(default_factory=list)
    unpinned: list = field(default_factory=list)
    conditional: tuple = (0, {}, b"")
    range: tuple = (0, {}, b"")
    upstreams_used: set = field(default_factory=set)
    replica_ports: set = field(default_factory=set)
    after_kill: list = field(default_factory=list)
    pinned_after_kill: tuple = (0, {}, b"")


@pytest.fixture(scope="module")
def front(replicas, live_tmp) -> Front:
    if not shutil.which("nginx"):
        pytest.skip("nginx is not installed: nginx.conf was not run (./run test installs it)")
    prerequisite(all(r.url for r in replicas.values()), "starting the replicas")
    one, two = replicas["tessera-1"], replicas["tessera-2"]
    with open(NGINX_CONF, encoding="utf-8") as f:
        conf = f.read()
    ndir = os.path.join(live_tmp, "nginx")
    os.makedirs(ndir)
    port = free_port()
    path = local_nginx_conf(conf, ndir, {"tessera-1": port_of(one.url), "tessera-2": port_of(two.url)}, port)
    ng = Proc("nginx", ["nginx", "-e", os.path.join(ndir, "error.log"), "-p", ndir, "-c", path, "-g", "daemon off;"],
              os.environ.copy(), live_tmp, stdout_pipe=False)
    base = f"http://127.0.0.1:{port}"
    r = Front()
    deadline = time.time() + 10
    while time.time() < deadline and http_get(base + "/nginx-health", timeout=2)[0] != 200:
        time.sleep(0.1)
    r.up = http_get(base + "/nginx-health")[0] == 200
    r.tail = ng.tail()
    if not r.up:
        return r
    r.dataset = http_get(base + "/v1/datasets/demo")
    if r.dataset[0] != 200:
        return r
    h = json.loads(r.dataset[2]).get("content_hash")
    tile = f"{base}/v1/datasets/demo/tiles/0/0/0"
    r.pinned = [http_get(f"{tile}?v={h}") for _ in range(2)]
    r.unpinned = [http_get(tile) for _ in range(2)]
    r.conditional = http_get(tile, {"If-None-Match": r.unpinned[0][1].get("etag") or '"x"'})
    r.range = http_get(f"{base}/v1/datasets/demo/pyramid?v={h}", {"Range": "bytes=0-99"})
    for _ in range(10):
        http_get(f"{base}/v1/datasets/demo")
    time.sleep(0.2)
    with open(os.path.join(ndir, "access.log"), encoding="utf-8") as f:
        r.upstreams_used = {int(p) for p in re.findall(r"upstream=127\.0\.0\.1:(\d+)", f.read())}
    r.replica_ports = {port_of(one.url), port_of(two.url)}
    one.proc.stop(signal.SIGKILL)
    r.after_kill = [http_get(tile)[0] for _ in range(10)]
    r.pinned_after_kill = http_get(f"{tile}?v={h}")
    return r


def answered(front: Front) -> Front:
    prerequisite(front.up and front.dataset[0] == 200, "nginx in front of the replicas")
    return front


def test_nginx_runs_in_front_of_both_replicas(front):
    assert front.up, front.tail


def test_dataset_through_the_front_is_200(front):
    prerequisite(front.up, "starting nginx")
    st, _, body = front.dataset
    assert st == 200, f"{st} {body[:200]!r}"


def test_pinned_tile_is_a_miss_then_a_hit_with_the_same_bytes(front):
    """A ?v= pinned tile (Cache-Control immutable)."""
    a, b = answered(front).pinned
    assert (a[0] == 200 and "immutable" in a[1].get("cache-control", "") and a[1].get("x-cache-status") == "MISS"
            and b[1].get("x-cache-status") == "HIT" and a[2] == b[2]), \
        f"{a[0]} {a[1].get('cache-control')} {a[1].get('x-cache-status')} then {b[1].get('x-cache-status')}"


def test_unpinned_tile_is_not_cached(front):
    u1, u2 = answered(front).unpinned
    assert u1[0] == 200 and u2[1].get("x-cache-status") == "BYPASS", f"{u1[0]} {u2[1].get('x-cache-status')}"


def test_if_none_match_reaches_the_replicas(front):
    assert answered(front).conditional[0] == 304, f"got {front.conditional[0]}"


def test_range_request_for_the_pinned_pyramid_passes_through(front):
    """206, 100 bytes, not cached."""
    st, headers, body = answered(front).range
    assert st == 206 and len(body) == 100 and headers.get("x-cache-status") == "BYPASS", \
        f"{st} {len(body)} bytes {headers.get('x-cache-status')}"


def test_requests_are_spread_over_both_replicas(front):
    """Round robin."""
    answered(front)
    assert front.replica_ports <= front.upstreams_used, \
        f"upstreams used {front.upstreams_used}, replicas {front.replica_ports}"


def test_every_request_answered_with_one_replica_killed(front):
    """tessera-1 killed: 10/10 requests still answered 200 (proxy_next_upstream)."""
    codes = answered(front).after_kill
    assert codes and all(c == 200 for c in codes), f"codes {codes}"


def test_pinned_tile_still_a_hit_with_one_replica_killed(front):
    assert answered(front).pinned_after_kill[1].get("x-cache-status") == "HIT"
