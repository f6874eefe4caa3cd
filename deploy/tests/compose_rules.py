"""deploy/compose.yaml: its model as Docker Compose's own loader gives it, and the
rules of its start-up chain (s3 -> create-bucket -> build-demo -> tessera-1/2 -> nginx)."""

from __future__ import annotations

import json
import os
import subprocess

import yaml

from commands import arg_after
from deploy_paths import DEPLOY, NGINX_CONF
from manifests import split_image


def compose_model(compose_bin: str | None, path: str) -> tuple[dict | None, str]:
    """The compose file as `docker-compose config` normalises it (None and the loader's
    error when it refuses the file); without the binary, the YAML as written."""
    if compose_bin:
        p = subprocess.run([compose_bin, "-f", path, "config", "--format", "json"],
                           capture_output=True, text=True, cwd=os.path.dirname(path),
                           env={**os.environ, "DOCKER_HOST": "unix:///nonexistent"})
        if p.returncode != 0:
            return None, (p.stderr or p.stdout).strip()
        return json.loads(p.stdout), ""
    with open(path, encoding="utf-8") as f:
        return yaml.safe_load(f), ""


def compose_rules(model: dict) -> list[str]:
    """The problems of the services' chain, images and health checks (none: all hold)."""
    problems = []
    services = model.get("services") or {}
    want = {"s3", "create-bucket", "build-demo", "tessera-1", "tessera-2", "nginx"}
    if set(services) != want:
        problems.append(f"services are {sorted(services)}, expected {sorted(want)}")
        return problems
    for name, s in services.items():
        img = s.get("image") or ""
        _, tag, digest = split_image(img)
        if not (tag or digest) or tag == "latest":
            problems.append(f"{name}: image {img!r} not pinned by tag")

    def deps(name):
        d = services[name].get("depends_on") or {}
        return d if isinstance(d, dict) else {k: {"condition": "service_started"} for k in d}

    build = services["build-demo"]
    bcmd = build.get("command") or []
    out = arg_after(bcmd, "-o")
    if not bcmd or bcmd[0] != "build" or not out or not out.startswith("s3://"):
        problems.append(f"build-demo: command {bcmd} is not `build INPUT -o s3://...`")
    bucket = out.split("/")[2] if out and out.startswith("s3://") else None
    if (deps("build-demo").get("create-bucket") or {}).get("condition") != "service_completed_successfully":
        problems.append("build-demo does not wait for create-bucket to complete")
    cb = " ".join(services["create-bucket"].get("command") or [])
    if not bucket or f"PUT http://s3:5000/{bucket}" not in cb:
        problems.append(f"create-bucket does not PUT the bucket {bucket} on s3:5000")
    if (deps("create-bucket").get("s3") or {}).get("condition") != "service_healthy":
        problems.append("create-bucket does not wait for s3 to be healthy")
    for name in ("tessera-1", "tessera-2"):
        s = services[name]
        cmd = s.get("command") or []
        if not cmd or cmd[0] != "serve" or out not in cmd:
            problems.append(f"{name}: command {cmd} does not serve {out}")
        if arg_after(cmd, "--listen") != "0.0.0.0:8080":
            problems.append(f"{name}: does not listen on 0.0.0.0:8080")
        if (deps(name).get("build-demo") or {}).get("condition") != "service_completed_successfully":
            problems.append(f"{name} does not wait for build-demo to complete")
        test = " ".join(str(x) for x in (s.get("healthcheck") or {}).get("test") or [])
        if "/healthz/ready" not in test:
            problems.append(f"{name}: healthcheck does not use /healthz/ready")
        env = s.get("environment") or {}
        if isinstance(env, list):
            env = dict(e.split("=", 1) for e in env)
        if env.get("AWS_ENDPOINT_URL") != "http://s3:5000" or str(env.get("AWS_ALLOW_HTTP")).lower() != "true":
            problems.append(f"{name}: AWS_ENDPOINT_URL/AWS_ALLOW_HTTP do not point at the s3 service over http")
        if not s.get("read_only"):
            problems.append(f"{name}: root file system not read-only")
    for name in ("tessera-1", "tessera-2"):
        if (deps("nginx").get(name) or {}).get("condition") != "service_healthy":
            problems.append(f"nginx does not wait for {name} to be healthy")
    for name in ("s3", "tessera-1", "tessera-2", "nginx"):
        hc = services[name].get("healthcheck") or {}
        if not hc.get("test") or hc.get("disable"):
            problems.append(f"{name}: no healthcheck")
    vols = services["nginx"].get("volumes") or []
    srcs = [(v.get("source"), v.get("target")) if isinstance(v, dict) else tuple(v.split(":")[:2]) for v in vols]
    if not any(t == "/etc/nginx/nginx.conf" and os.path.normpath(os.path.join(DEPLOY, s)) == NGINX_CONF for s, t in srcs):
        problems.append("nginx does not mount deploy/nginx/nginx.conf at /etc/nginx/nginx.conf")
    return problems
