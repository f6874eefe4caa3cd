"""compose.yaml's commands: the S3 server (moto on loopback), the create-bucket command
(twice), build-demo as written, and the two replicas serving its pyramid, each passing
compose's healthcheck command."""

from __future__ import annotations

import pytest

REPLICAS = ["tessera-1", "tessera-2"]


def test_moto_server_is_up(moto):
    if moto is None:
        pytest.skip("no object storage (serve --help names no s3://, or DEPLOY_CHECK_NO_S3 is set): "
                    "the compose commands run with s3://tessera/demo.tess mapped to a local file")
    assert moto.up, moto.proc.tail()


def test_create_bucket_creates_the_bucket(create_bucket):
    p = create_bucket[0]
    assert p.returncode == 0, p.stderr.strip()


def test_create_bucket_again_succeeds(create_bucket):
    """Restarts are harmless."""
    p = create_bucket[1]
    assert p.returncode == 0, p.stderr.strip()


def test_build_demo_writes_the_pyramid(demo):
    assert demo.build.ok, demo.build.log
    print(f"build-demo wrote {demo.build.what} in {demo.build.seconds:.1f} s")


@pytest.mark.parametrize("name", REPLICAS)
def test_replica_starts(replicas, name):
    r = replicas[name]
    assert r.url is not None, f"`{' '.join(r.command)}`: {r.proc.tail()}"


@pytest.mark.parametrize("name", REPLICAS)
def test_replica_serves_the_demo_dataset(replicas, name):
    r = replicas[name]
    assert r.dataset_status == 200, f"{r.dataset_status} {r.dataset_body[:200]!r}"


@pytest.mark.parametrize("name", REPLICAS)
def test_replica_passes_compose_healthcheck(replicas, name):
    """compose's healthcheck command (/healthz/ready) exits 0."""
    r = replicas[name]
    assert r.healthcheck_rc == 0, f"exit {r.healthcheck_rc}"
