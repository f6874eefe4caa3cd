"""deploy/nginx/nginx.conf: the rules it must follow (an upstream of both replicas
with passive health, next upstream on errors, a cache of pinned responses only), and
the same file rewritten to run on loopback."""

from __future__ import annotations

import os
import re


def nginx_rules(conf: str, replicas: list[str]) -> list[str]:
    """The problems of nginx.conf `conf` in front of `replicas` (none: all hold)."""
    problems = []
    text = re.sub(r"#[^\n]*", "", conf)
    up = re.search(r"upstream\s+(\S+)\s*\{(.*?)\}", text, re.S)
    if not up:
        return ["no upstream block"]
    servers = re.findall(r"server\s+(\S+?)(?::(\d+))?\s+([^;]*);", up.group(2))
    hosts = {h for h, _, _ in servers}
    if hosts != set(replicas):
        problems.append(f"upstream servers {sorted(hosts)} are not the replicas {replicas}")
    for h, port, params in servers:
        if port != "8080":
            problems.append(f"upstream {h}: port {port}, the replicas listen on 8080")
        if "max_fails=" not in params or "fail_timeout=" not in params:
            problems.append(f"upstream {h}: no max_fails/fail_timeout (passive health)")
    if not re.search(rf"proxy_pass\s+http://{re.escape(up.group(1))}\s*;", text):
        problems.append("no proxy_pass to the upstream")
    nu = re.search(r"proxy_next_upstream\s+([^;]*);", text)
    if not nu or not {"error", "timeout", "http_502", "http_503"} <= set(nu.group(1).split()):
        problems.append("proxy_next_upstream lacks error timeout http_502 http_503")
    if not re.search(r"proxy_cache_path\s", text) or not re.search(r"proxy_cache\s+\w+;", text):
        problems.append("no proxy_cache")
    if re.search(r"proxy_cache_valid", text) or re.search(r"proxy_ignore_headers[^;]*Cache-Control", text):
        problems.append("cache lifetimes must come from the replicas' Cache-Control")
    pinned = re.search(r"map\s+\$arg_v\s+\$(\w+)", text)
    for d in ("proxy_cache_bypass", "proxy_no_cache"):
        m = re.search(rf"{d}\s+([^;]*);", text)
        if not m or not pinned or f"${pinned.group(1)}" not in m.group(1) or "$http_range" not in m.group(1):
            problems.append(f"{d} does not exclude unpinned (no ?v=) and Range requests")
    return problems


def local_nginx_conf(conf: str, tmp: str, upstream_ports: dict, listen_port: int) -> str:
    """nginx.conf for loopback: replicas at 127.0.0.1:PORT, temp paths in `tmp`."""
    for d in ("cache", "client_body", "proxy", "fastcgi", "uwsgi", "scgi"):
        os.makedirs(os.path.join(tmp, d), exist_ok=True)
        os.chmod(os.path.join(tmp, d), 0o777)
    os.chmod(tmp, 0o755)
    c = re.sub(r"^\s*user\s+[^;]*;", "", conf, flags=re.M)
    c = c.replace("pid /tmp/nginx.pid;", f"pid {tmp}/nginx.pid;")
    c = c.replace("error_log /dev/stderr warn;", f"error_log {tmp}/error.log warn;")
    c = c.replace("access_log /dev/stdout tessera;", f"access_log {tmp}/access.log tessera;")
    c = c.replace("/var/cache/nginx/tessera", f"{tmp}/cache")
    c = re.sub(r"listen\s+8080;", f"listen 127.0.0.1:{listen_port};", c)
    for host, port in upstream_ports.items():
        c = re.sub(rf"server\s+{re.escape(host)}:8080", f"server 127.0.0.1:{port}", c)
    c = c.replace("http {", "http {\n" + "".join(
        f"    {d}_temp_path {tmp}/{d};\n"
        for d in ("client_body", "proxy", "fastcgi", "uwsgi", "scgi")), 1)
    path = os.path.join(tmp, "nginx.conf")
    with open(path, "w", encoding="utf-8") as f:
        f.write(c)
    return path
