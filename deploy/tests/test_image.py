"""`./run image` (deploy/image.py) in its cheap mode, `check`: no engine, no network.
The full run builds deploy/Dockerfile with podman from local base images and runs the
image for real (compose.yaml's services as containers, a replica killed, the
distributed build's part and assemble containers); it takes far longer than CI allows,
so CI checks its plan: the Dockerfile's base images are build arguments the script
supplies, every compose service maps onto a container in an order that respects its
dependencies, nginx's upstreams are container names, and the prerequisites are
reported. Broken copies must be refused."""

from __future__ import annotations

import os
import re
import subprocess
import sys

import pytest

from deploy_paths import COMPOSE, DEPLOY, DOCKERFILE, ROOT

IMAGE_PY = os.path.join(DEPLOY, "image.py")


def image_check(*extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, IMAGE_PY, "check", *extra], capture_output=True, text=True,
                          timeout=60, cwd=ROOT)


@pytest.fixture(scope="module")
def checked() -> subprocess.CompletedProcess:
    return image_check()


def planned_services(out: str) -> list[str]:
    """The services of the printed `podman run` lines, in order."""
    return re.findall(r"^  podman run .*?--network-alias (\S+)", out, re.M)


def test_image_check_passes(checked):
    assert checked.returncode == 0, (checked.stderr or checked.stdout).strip()[-2000:]


def test_every_base_image_argument_gets_a_local_base(checked):
    with open(DOCKERFILE, encoding="utf-8") as f:
        args = re.findall(r"^FROM \$\{(\w+)\}", f.read(), re.M)
    assert len(args) == 3, args
    for arg in args:
        assert re.search(rf"^  {arg}: \S+ -> localhost/\S+", checked.stdout, re.M), f"no local base for {arg}"
        assert f"--build-arg {arg}=localhost/" in checked.stdout, f"podman build is not given {arg}"


def test_plan_starts_every_compose_service_after_its_dependencies(checked, compose_loaded):
    model, err = compose_loaded
    assert model is not None, err
    order = planned_services(checked.stdout)
    assert sorted(order) == sorted(model["services"]), order
    for name, s in model["services"].items():
        for dep in s.get("depends_on") or {}:
            assert order.index(dep) < order.index(name), f"{name} is started before {dep}"


def test_replicas_run_as_compose_says(checked):
    """Read-only root, no capabilities, no new privileges, the S3 endpoint by service name."""
    lines = [ln for ln in checked.stdout.splitlines() if re.search(r"--network-alias tessera-\d ", ln)]
    assert len(lines) == 2, lines
    for ln in lines:
        for want in ("--read-only", "--tmpfs /tmp", "--cap-drop ALL", "--security-opt no-new-privileges",
                     "AWS_ENDPOINT_URL=http://s3:5000", " serve s3://"):
            assert want in ln, f"{want!r} not in {ln}"


def test_prerequisites_are_reported_and_match_run(checked):
    """The packages the check reports are those `./run image` installs."""
    with open(os.path.join(ROOT, "run"), encoding="utf-8") as f:
        m = re.search(r"^IMAGE_PACKAGES=\(([^)]*)\)", f.read(), re.M)
    assert m, "./run has no IMAGE_PACKAGES"
    reported = re.findall(r"^  ([\w.+-]+): (?:installed|missing)$", checked.stdout, re.M)
    assert reported == m.group(1).split()


# ---------------------------------------------------------------- broken copies ------


def test_check_refuses_a_literal_base_image(tmp_path):
    with open(DOCKERFILE, encoding="utf-8") as f:
        text = f.read()
    assert "FROM ${NODE_IMAGE} AS viewer-assets" in text
    path = tmp_path / "Dockerfile"
    path.write_text(text.replace("FROM ${NODE_IMAGE} AS viewer-assets", "FROM node:22.12.0-bookworm-slim AS viewer-assets"))
    p = image_check("--dockerfile", str(path))
    assert p.returncode != 0 and "FROM node:22.12.0-bookworm-slim is not a build argument" in p.stderr, p.stderr


def test_check_refuses_a_compose_image_it_has_no_stand_in_for(tmp_path):
    with open(COMPOSE, encoding="utf-8") as f:
        text = f.read()
    assert "image: nginx:1.28.0-alpine" in text
    (tmp_path / "nginx").mkdir()
    path = tmp_path / "compose.yaml"
    path.write_text(text.replace("image: nginx:1.28.0-alpine", "image: nginx:1.29.0-alpine"))
    p = image_check("--compose", str(path))
    assert p.returncode != 0 and "nginx:1.29.0-alpine has no local stand-in" in p.stderr, p.stderr
