"""Fixtures of the live tests: the commands in deploy/'s files run for real against a
locally built tessera-server, on loopback. They share one temporary folder, one moto S3
server (compose's `s3` service), the bucket, the demo pyramid built into it and the
two replicas serving it; every process started is stopped, by its own pid, at the end.

A fixture that runs commands records what happened, and the tests assert on the
record, so each test holds one check whatever order the tests run in."""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
import time

import pytest

from commands import arg_after, port_of, rewrite_listen, unescape_compose
from deploy_paths import ROOT
from outcomes import Built, Demo, Moto, Replica, prerequisite
from processes import Proc, free_port, http_get, run, run_healthcheck


@pytest.fixture(scope="session")
def server_bin(request) -> str:
    server = request.config.getoption("--server")
    if not server:
        pytest.fail("no tessera-server binary (build it: cargo build -p tessera-server)")
    return os.path.abspath(server)


@pytest.fixture(scope="session")
def client_bin() -> str | None:
    """The `tessera` client for the load Jobs: $TESSERA_CLIENT, else target/debug/tessera,
    else target/release/tessera (./run test's cargo test builds the debug one)."""
    for b in (os.environ.get("TESSERA_CLIENT"), os.path.join(ROOT, "target", "debug", "tessera"),
              os.path.join(ROOT, "target", "release", "tessera")):
        if b and os.access(b, os.X_OK):
            return b
    return None


@pytest.fixture(scope="session")
def has_s3(server_bin) -> bool:
    """Object storage for compose's commands: the binary serves s3:// and
    DEPLOY_CHECK_NO_S3 is not set (then s3://tessera/demo.tess is a local file)."""
    return "s3://" in run([server_bin, "serve", "--help"]).stdout and not os.environ.get("DEPLOY_CHECK_NO_S3")


@pytest.fixture(scope="session")
def live_tmp(request):
    tmp = tempfile.mkdtemp(prefix="tessera-deploy-")
    os.chmod(tmp, 0o755)  # nginx's workers (nobody, when run as root) reach their cache in it
    yield tmp
    Proc.stop_all()
    if request.config.getoption("--keep"):
        print(f"\ndeploy: logs and files kept in {tmp}", file=sys.stderr)
    else:
        shutil.rmtree(tmp, ignore_errors=True)


@pytest.fixture(scope="session")
def base_env() -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("AWS_", "TESSERA_"))}
    env["RUST_LOG"] = "info"
    return env


@pytest.fixture(scope="session")
def small_pyramid(server_bin, live_tmp, base_env) -> Built:
    """A small local pyramid (build synthetic:257) in a folder of its own, for the
    image's CMD (its /data) and the load Jobs' server."""
    data = os.path.join(live_tmp, "data")
    os.makedirs(data)
    path = os.path.join(data, "demo.tess")
    p = run([server_bin, "build", "synthetic:257", "-o", path, "--quiet"], base_env)
    return Built(path, p.returncode == 0, p.stderr[-500:])


@pytest.fixture(scope="session")
def services(compose_loaded) -> dict:
    model, err = compose_loaded
    if model is None:
        pytest.fail(f"compose.yaml was not parsed: {err}")
    return model["services"]


@pytest.fixture(scope="session")
def moto(has_s3, tools, live_tmp, base_env) -> Moto | None:
    if not has_s3:
        return None
    port = free_port()
    proc = Proc("moto", [os.path.join(tools.venv_bin, "moto_server"), "-H", "127.0.0.1", "-p", str(port)],
                base_env, live_tmp, stdout_pipe=False)
    endpoint = f"http://127.0.0.1:{port}"
    deadline = time.time() + 30
    while time.time() < deadline and http_get(endpoint + "/moto-api/", timeout=2)[0] != 200:
        time.sleep(0.2)
    return Moto(proc, endpoint, http_get(endpoint + "/moto-api/")[0] == 200)


@pytest.fixture(scope="session")
def create_bucket(moto, services, base_env) -> list:
    """The create-bucket service's command, with s3:5000 on loopback, run twice (a
    restart must be harmless)."""
    if moto is None:
        pytest.skip("no object storage: compose's s3:// is a local file")
    prerequisite(moto.up, "the moto server")
    if not shutil.which("curl"):
        pytest.fail("curl is not installed")
    cb = [unescape_compose(a).replace("http://s3:5000", moto.endpoint) for a in services["create-bucket"]["command"]]
    return [run(cb, base_env, timeout=30) for _ in range(2)]


@pytest.fixture(scope="session")
def s3_env(moto, services) -> dict:
    """build-demo's environment, its endpoint the moto server ({} without S3)."""
    if moto is None:
        return {}
    env = services["build-demo"].get("environment") or {}
    return {k: (moto.endpoint if k == "AWS_ENDPOINT_URL" else str(v)) for k, v in env.items()}


@pytest.fixture(scope="session")
def demo(has_s3, moto, create_bucket, services, s3_env, server_bin, live_tmp, base_env) -> Demo:
    """build-demo's command as written (into S3, or a local file without it)."""
    if moto is not None:
        prerequisite(all(p.returncode == 0 for p in create_bucket), "create-bucket")
    bcmd = list(services["build-demo"]["command"])
    url = arg_after(bcmd, "-o")
    d = Demo(url, os.path.join(live_tmp, "s3-demo", os.path.basename(url)), has_s3)
    os.makedirs(os.path.dirname(d.local))
    t0 = time.time()
    p = run([server_bin] + [d.map(a) for a in bcmd] + ["--quiet"], {**base_env, **s3_env}, timeout=600)
    d.build = Built(d.local, p.returncode == 0, (p.stderr or p.stdout)[-800:], time.time() - t0,
                    url if has_s3 else "a local file")
    return d


@pytest.fixture(scope="session")
def replicas(demo, services, server_bin, s3_env, live_tmp, base_env) -> dict[str, Replica]:
    """tessera-1 and tessera-2 serving the demo pyramid: each one's dataset document and
    compose's healthcheck command (/healthz/ready), right after it started."""
    prerequisite(demo.build.ok, "build-demo")
    out = {}
    for name in ("tessera-1", "tessera-2"):
        c = services[name]["command"]
        pr = Proc(name, [server_bin] + [demo.map(a) for a in rewrite_listen(c)], {**base_env, **s3_env}, live_tmp)
        r = out[name] = Replica(name, c, pr, pr.wait_listening())
        if r.url is None:
            continue
        r.dataset_status, _, r.dataset_body = http_get(r.url + "/v1/datasets/demo")
        hct = (services[name].get("healthcheck") or {}).get("test") or []
        r.healthcheck_rc = run_healthcheck(hct, port_of(r.url))
    return out
