"""deploy/nginx/nginx.conf: its rules, and `nginx -t` on it rewritten for loopback; a
broken copy must be rejected."""

from __future__ import annotations

import os
import shutil
import subprocess

import pytest

from deploy_paths import NGINX_CONF
from nginx_rules import local_nginx_conf, nginx_rules

REPLICAS = ["tessera-1", "tessera-2"]


def read_conf() -> str:
    with open(NGINX_CONF, encoding="utf-8") as f:
        return f.read()


def test_nginx_rules_hold():
    """An upstream of both replicas with passive health, next upstream on
    error/timeout/502/503, a cache of ?v= pinned responses only."""
    problems = nginx_rules(read_conf(), REPLICAS)
    assert not problems, "; ".join(problems)


def test_nginx_t_accepts_nginx_conf(tmp_path):
    """Upstreams and paths rewritten for loopback."""
    if not shutil.which("nginx"):
        pytest.skip("nginx is not installed (./run test installs it)")
    tmp = str(tmp_path)
    local = local_nginx_conf(read_conf(), tmp, {"tessera-1": 1, "tessera-2": 2}, 1)
    p = subprocess.run(["nginx", "-t", "-q", "-e", os.path.join(tmp, "error.log"), "-p", tmp, "-c", local],
                       capture_output=True, text=True)
    assert p.returncode == 0, p.stderr.strip()


def test_nginx_rules_catch_no_passive_health_and_no_next_upstream_on_502_503():
    bad = read_conf().replace("http_502 http_503;", ";", 1).replace("max_fails=2 fail_timeout=10s", "")
    assert len(nginx_rules(bad, REPLICAS)) >= 2
