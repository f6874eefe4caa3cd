"""Where deploy/'s files are, and the constants the checks share."""

from __future__ import annotations

import os

TESTS = os.path.dirname(os.path.abspath(__file__))
DEPLOY = os.path.dirname(TESTS)
ROOT = os.path.dirname(DEPLOY)
K8S_DIR = os.path.join(DEPLOY, "k8s")
DOCKERFILE = os.path.join(DEPLOY, "Dockerfile")
HADOLINT_CONFIG = os.path.join(DEPLOY, ".hadolint.yaml")
DOCKERIGNORE = os.path.join(ROOT, ".dockerignore")
COMPOSE = os.path.join(DEPLOY, "compose.yaml")
NGINX_CONF = os.path.join(DEPLOY, "nginx", "nginx.conf")

# Kubernetes versions validated against: 1.33 is the oldest where everything the
# manifests use is GA (Job backoffLimitPerIndex and podFailurePolicy, HPA v2, PDB v1);
# 1.37 is the newest whose schemas kubernetes-validate 1.37.0 bundles.
K8S_VERSIONS = ["1.33", "1.37"]

# The build Jobs' input (synthetic:16385) is rewritten to this so that 16 parts (each
# reads the whole input), the assemble and a single build for comparison take seconds.
# compose's build-demo runs as written (synthetic:4097).
PARTS_SIZE = "synthetic:4097"

# The shared libraries debian:12-slim has, which is all the images' binaries may link
# (the runtime stage installs no library).
SLIM_LIBRARIES = {
    "linux-vdso.so.1", "libgcc_s.so.1", "libm.so.6", "libc.so.6", "ld-linux-x86-64.so.2",
    "/lib64/ld-linux-x86-64.so.2", "libpthread.so.0", "libdl.so.2", "librt.so.1",
}


def k8s(*parts: str) -> str:
    """A path under deploy/k8s."""
    return os.path.join(K8S_DIR, *parts)


def rel(path: str) -> str:
    """`path` relative to the repository root, as the test names show it."""
    return os.path.relpath(path, ROOT)
