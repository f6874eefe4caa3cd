"""The Kubernetes Deployment's container, run as Kubernetes would: its ConfigMap as
environment, its args expanded, and each probe's path answered 200."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from deploy_paths import k8s
from k8s_rules import container_env, expand, pod_spec
from outcomes import prerequisite
from processes import Proc, http_get

PROBES = ["readinessProbe", "livenessProbe", "startupProbe"]


@dataclass
class Pod:
    args: list
    env: dict
    url: str | None
    tail: str
    probes: dict = field(default_factory=dict)


@pytest.fixture(scope="module")
def pod(rendered, has_s3, s3_env, demo, server_bin, live_tmp, base_env) -> Pod:
    """deploy/k8s/base's Deployment serving the demo pyramid (from S3, or its local
    file), and what each probe's path answered."""
    prerequisite(demo.build.ok, "build-demo")
    base = rendered.get(k8s("base"), [])
    dep = next((o for o in base if o["kind"] == "Deployment"), None)
    if dep is None:
        pytest.fail("deploy/k8s/base has no Deployment")
    c = pod_spec(dep)["containers"][0]
    env, _ = container_env(c, {(o["kind"], o["metadata"]["name"]): o for o in base})
    env["TESSERA_LISTEN"] = "127.0.0.1:0"
    if has_s3:
        env.update({k: v for k, v in s3_env.items() if k.startswith("AWS_")})
        env["AWS_ALLOW_HTTP"] = "true"
    else:
        env["DATASET_URL"] = demo.local
    pr = Proc("k8s-deployment", [server_bin] + [expand(str(a), env) for a in (c.get("args") or [])],
              {**base_env, **env}, live_tmp)
    p = Pod(c.get("args") or [], env, pr.wait_listening(), pr.tail())
    if p.url:
        for probe in PROBES:
            path = ((c.get(probe) or {}).get("httpGet") or {}).get("path")
            if path:
                p.probes[probe] = (path, *http_get(p.url + path))
        pr.stop()
    return p


def test_deployment_container_starts_with_its_configmap(pod):
    names = ", ".join(k for k in sorted(pod.env) if k.startswith("TESSERA_"))
    assert pod.url is not None, f"`tessera-server {' '.join(pod.args)}` with {names}: {pod.tail}"


@pytest.mark.parametrize("probe", PROBES)
def test_probe_path_is_200(pod, probe):
    prerequisite(pod.url is not None, "starting the Deployment's container")
    if probe not in pod.probes:
        pytest.skip(f"the Deployment has no {probe}")
    path, st, _, body = pod.probes[probe]
    assert st == 200, f"GET {path}: {st} {body[:200]!r}"
