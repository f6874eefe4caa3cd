"""Shared fixtures of deploy/'s checks: the command-line options deploy/check.sh passes,
the tools from its virtualenv, the rendered manifests and compose.yaml's model.

The tools (kubectl, hadolint, Docker Compose's binary, moto_server) are looked up beside the
Python that runs pytest, i.e. in the virtualenv deploy/check.sh makes; a tool that is
missing fails the tests that need it."""

from __future__ import annotations

import functools
import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass

import pytest

from compose_rules import compose_model
from deploy_paths import COMPOSE, ROOT
from k8s_rules import semantic_checks
from manifests import RenderError, kubectl_version, kustomize_dirs, render


def pytest_addoption(parser):
    g = parser.getgroup("deploy", "deploy/check.sh")
    g.addoption("--server", help="the tessera-server binary the live tests run")
    g.addoption("--no-live", action="store_true", help="skip the tests that run commands")
    g.addoption("--keep", action="store_true", help="keep the live tests' temporary folder")


def pytest_collection_modifyitems(config, items):
    # The file checks first, then the live tests (live/), and a test that stops the
    # shared S3 server after every other one (a stable sort keeps the rest in order).
    def live(item) -> bool:
        return item.path.parent.name == "live"

    items.sort(key=lambda item: (live(item), item.get_closest_marker("stops_s3") is not None))
    if config.getoption("--no-live"):
        config.hook.pytest_deselected(items=[item for item in items if live(item)])
        items[:] = [item for item in items if not live(item)]


@dataclass(frozen=True)
class Tools:
    venv_bin: str
    hadolint: str | None
    compose: str | None

    def version(self, tool: str | None, *args: str) -> str:
        if not tool:
            return "missing"
        return subprocess.run([tool, *args], capture_output=True, text=True).stdout.strip()


@functools.cache
def find_tools() -> Tools:
    venv_bin = os.path.dirname(sys.executable)
    try:
        import compose

        compose_bin = os.path.join(os.path.dirname(compose.__file__), "docker-compose")
    except ImportError:
        compose_bin = None
    return Tools(
        venv_bin=venv_bin,
        hadolint=shutil.which("hadolint", path=venv_bin),
        compose=compose_bin if compose_bin and os.access(compose_bin, os.X_OK) else None,
    )


def pytest_report_header(config):
    t = find_tools()
    server = config.getoption("--server")
    return [
        f"deploy tools ({t.venv_bin}): {kubectl_version()}, {t.version(t.hadolint, '--version')}, "
        f"docker-compose {t.version(t.compose, 'version', '--short')}",
        "live tests: " + ("off (--no-live)" if config.getoption("--no-live")
                          else f"against {os.path.relpath(server, ROOT) if server else 'no tessera-server binary'}"),
    ]


@pytest.fixture(scope="session")
def tools() -> Tools:
    return find_tools()


@pytest.fixture(scope="session")
def renderings() -> dict[str, list[dict] | RenderError]:
    """Every Kustomize directory's objects, or the error that stopped its rendering."""
    out: dict[str, list[dict] | RenderError] = {}
    for d in kustomize_dirs():
        try:
            out[d] = render(d)
        except RenderError as e:
            out[d] = e
    return out


@pytest.fixture(scope="session")
def rendered(renderings) -> dict[str, list[dict]]:
    """The objects of every Kustomize directory that renders."""
    return {d: objs for d, objs in renderings.items() if not isinstance(objs, RenderError)}


@pytest.fixture(scope="session")
def tessera_envs(request) -> tuple[set[str], str]:
    """The TESSERA_* variables `tessera-server serve` reads, and where that was read:
    its --help when there is a binary, else the server's sources."""
    server = request.config.getoption("--server")
    if server:
        p = subprocess.run([server, "serve", "--help"], capture_output=True, text=True)
        names = set(re.findall(r"\[env:\s*(TESSERA_[A-Z0-9_]+)", p.stdout))
        if names:
            return names, "`tessera-server serve --help`"
    names = set()
    d = os.path.join(ROOT, "server", "src", "serve")
    for f in os.listdir(d):
        if f.endswith(".rs"):
            with open(os.path.join(d, f), encoding="utf-8") as fh:
                names |= set(re.findall(r'env\s*=\s*"(TESSERA_[A-Z0-9_]+)"', fh.read()))
    return names, "server/src/serve/*.rs (no binary)"


@pytest.fixture(scope="session")
def semantics(rendered, tessera_envs) -> dict[str, tuple[list[str], dict]]:
    """The semantic rules' problems and outputs per Kustomize directory, with
    ConfigMaps/PVCs resolvable across the renderings of one namespace (the assemble Job
    uses the parts step's ConfigMap and volume)."""
    universe_by_ns: dict = {}
    for objs in rendered.values():
        for o in objs:
            ns = (o.get("metadata") or {}).get("namespace")
            universe_by_ns.setdefault(ns, {})[(o["kind"], o["metadata"]["name"])] = o
    out = {}
    for d, objs in rendered.items():
        ns = next(((o.get("metadata") or {}).get("namespace") for o in objs if o["kind"] != "Namespace"), None)
        out[d] = semantic_checks(objs, universe_by_ns.get(ns, {}), tessera_envs[0])
    return out


@pytest.fixture(scope="session")
def compose_loaded(tools) -> tuple[dict | None, str]:
    """compose.yaml through `docker-compose config` (the YAML as written without it)."""
    return compose_model(tools.compose, COMPOSE)
