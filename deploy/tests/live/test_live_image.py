"""The image: its binary links only what debian:12-slim has, its ENTRYPOINT+CMD serves
(/data a local folder with a pyramid), its HEALTHCHECK command passes against the
server and fails on a 404 and on a closed port, and SIGTERM stops it cleanly."""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass

import pytest

from commands import port_of, rewrite_listen
from outcomes import prerequisite
from deploy_paths import SLIM_LIBRARIES
from dockerfile_rules import dockerfile_parts
from processes import (
    Proc,
    apt_closure,
    http_get,
    linked_library_paths,
    package_owning,
    run_healthcheck,
)


@dataclass
class ImageRun:
    argv: list
    healthcheck: list | None
    url: str | None = None
    tail: str = ""
    live: int = 0
    ready: tuple = (0, b"")
    healthcheck_rc: int | None = None
    healthcheck_404_rc: int | None = None
    stop_rc: int | None = None
    healthcheck_closed_rc: int | None = None


@pytest.fixture(scope="module")
def image(server_bin, small_pyramid, live_tmp, base_env) -> ImageRun:
    """The image's ENTRYPOINT + CMD with --listen on loopback and /data the small
    pyramid's folder; its HEALTHCHECK command while it runs and after SIGTERM."""
    prerequisite(small_pyramid.ok, "the small pyramid")
    df = dockerfile_parts()
    argv = (df.get("ENTRYPOINT") or []) + (df.get("CMD") or [])
    data = os.path.dirname(small_pyramid.path)
    r = ImageRun(argv, df.get("HEALTHCHECK"))
    srv = Proc("image-cmd", [server_bin] + [data if a == "/data" else a for a in rewrite_listen(argv)[1:]],
               base_env, live_tmp)
    r.url = srv.wait_listening()
    r.tail = srv.tail()
    if r.url is None:
        return r
    r.live = http_get(r.url + "/healthz/live")[0]
    status, _, body = http_get(r.url + "/healthz/ready")
    r.ready = (status, body)
    port = port_of(r.url)
    if r.healthcheck:
        r.healthcheck_rc = run_healthcheck(r.healthcheck, port)
        r.healthcheck_404_rc = run_healthcheck(r.healthcheck, port, "/no/such/path")
    r.stop_rc = srv.stop()
    if r.healthcheck:
        r.healthcheck_closed_rc = run_healthcheck(r.healthcheck, port)
    return r


def started(image: ImageRun) -> ImageRun:
    prerequisite(image.url is not None, "the image's command")
    return image


def with_healthcheck(image: ImageRun) -> ImageRun:
    started(image)
    if not image.healthcheck:
        pytest.fail("the Dockerfile's final stage has no exec-form HEALTHCHECK")
    return image


def test_server_links_only_what_the_image_installs(server_bin):
    """Every shared library the server loads is in debian:12-slim, or comes from a
    package the final stage installs or one of their dependencies (libproj25 and what
    it pulls in: the server links PROJ for every CRS)."""
    for tool in ("ldd", "dpkg-query", "apt-cache"):
        if not shutil.which(tool):
            pytest.skip(f"{tool} is not installed")
    libs = linked_library_paths(server_bin)
    assert libs
    packages = dockerfile_parts()["apt_packages"]
    assert "libproj25" in packages, packages
    closure = apt_closure(packages)
    for name, path in sorted(libs.items()):
        if name in SLIM_LIBRARIES:
            continue
        owner = package_owning(path)
        assert owner in closure, f"{name} ({path}) is from {owner}, which the image does not install"


def test_small_pyramid_for_the_cmd_builds(small_pyramid):
    assert small_pyramid.ok, small_pyramid.log


def test_image_cmd_starts(image):
    """`tessera-server serve --listen 0.0.0.0:8080 /data` (listen 127.0.0.1:0)."""
    assert image.url is not None, f"`{' '.join(image.argv)}`: {image.tail}"


def test_healthz_live_is_200(image):
    assert started(image).live == 200, f"got {image.live}"


def test_healthz_ready_is_200(image):
    status, body = started(image).ready
    assert status == 200, f"got {status} {body[:200]!r}"


def test_healthcheck_exits_0_against_the_server(image):
    assert with_healthcheck(image).healthcheck_rc == 0


def test_healthcheck_fails_on_a_404(image):
    assert with_healthcheck(image).healthcheck_404_rc != 0


def test_sigterm_stops_the_server_cleanly(image):
    assert started(image).stop_rc == 0, f"exit {image.stop_rc}"


def test_healthcheck_fails_when_nothing_listens(image):
    assert with_healthcheck(image).healthcheck_closed_rc != 0
