"""The Kubernetes manifests (deploy/k8s): every Kustomize directory renders (with
Kustomize itself: the pinned kubectl's `kubectl kustomize`), every object is valid
against the Kubernetes schemas in strict mode (unknown fields are errors), and the
rules a reviewer checks hold; broken copies must be rejected."""

from __future__ import annotations

import copy
import os

import pytest

from deploy_paths import K8S_DIR, K8S_VERSIONS, k8s, rel
from k8s_rules import semantic_checks
from manifests import (
    RenderError,
    describe,
    kustomize_dirs,
    load_yaml_documents,
    referenced_files,
    render,
    validate_objects,
)

DIRS = kustomize_dirs()
DIR_IDS = [rel(d) for d in DIRS]


@pytest.mark.parametrize("directory", DIRS, ids=DIR_IDS)
def test_renders(renderings, directory):
    objs = renderings[directory]
    assert not isinstance(objs, RenderError), f"render {rel(directory)}: {objs}"
    assert objs, f"{rel(directory)} renders no object"


def test_every_yaml_file_is_used_by_a_kustomization():
    used = set().union(*(referenced_files(d) for d in DIRS))
    orphans = [rel(os.path.join(dirpath, f))
               for dirpath, _dirs, files in os.walk(K8S_DIR) for f in files
               if f.endswith((".yaml", ".yml")) and os.path.normpath(os.path.join(dirpath, f)) not in used]
    assert not orphans, f"unused: {orphans}"


@pytest.mark.parametrize("version", K8S_VERSIONS)
def test_files_as_written_are_valid(version):
    """Resource files one by one, before any transformation."""
    errors, count = [], 0
    for f in sorted(set().union(*(referenced_files(d) for d in DIRS))):
        if os.path.basename(f).startswith("kustomization") or "patch" in os.path.basename(f):
            continue
        docs = load_yaml_documents(f)
        count += len(docs)
        errors += [f"{rel(f)}: {e}" for e in validate_objects(docs, version)]
    assert count and not errors, "; ".join(errors) or "no manifest object found"


@pytest.mark.parametrize("version", K8S_VERSIONS)
@pytest.mark.parametrize("directory", DIRS, ids=DIR_IDS)
def test_rendering_is_valid(rendered, directory, version):
    errors = validate_objects(rendered[directory], version)
    assert not errors, "; ".join(errors)


@pytest.mark.parametrize("directory", DIRS, ids=DIR_IDS)
def test_semantic_rules_hold(semantics, tessera_envs, directory):
    problems, _ = semantics[directory]
    assert not problems, "; ".join(problems) + (
        f" (TESSERA_* names from {tessera_envs[1]}: {len(tessera_envs[0])} names)")


def test_base_starts_no_build(rendered):
    base = rendered.get(k8s("base"), [])
    assert base and not any(o["kind"] in ("Job", "CronJob") for o in base), \
        [describe(o) for o in base]


def outputs(semantics, key: str) -> set[str]:
    return {v for _, outs in semantics.values() for _, v in outs.get(key, [])}


def test_assemble_reads_what_the_indexed_job_writes(semantics):
    parts, assemble = outputs(semantics, "parts"), outputs(semantics, "assemble")
    assert parts and parts == assemble, f"parts write {parts}, assemble reads {assemble}"


def test_load_merge_reads_what_the_replay_writes(semantics):
    results, merged = outputs(semantics, "load-results"), outputs(semantics, "load-merge")
    assert results and results == merged, f"the shards write under {results}, the merge reads {merged}"


# ---------------------------------------------------------------- broken copies ------


def universe_of(objs: list[dict]) -> dict:
    return {(o["kind"], o["metadata"]["name"]): o for o in objs}


@pytest.fixture
def base(rendered) -> list[dict]:
    """A copy of deploy/k8s/base's objects, to break."""
    objs = rendered.get(k8s("base"))
    if not objs:
        pytest.skip("deploy/k8s/base did not render")
    return copy.deepcopy(objs)


def first(objs: list[dict], kind: str) -> dict:
    return next(o for o in objs if o["kind"] == kind)


def test_unknown_field_fails_strict_validation(base):
    dep = first(base, "Deployment")
    dep["spec"]["template"]["spec"]["containers"][0]["livenessProbe"]["httpGett"] = {"path": "/"}
    errs = validate_objects([dep], K8S_VERSIONS[-1])
    assert errs and "httpGett" in errs[0], "livenessProbe.httpGett validated"


def test_wrong_type_fails_validation(base):
    first(base, "Service")["spec"]["ports"][0]["port"] = "eighty"
    assert validate_objects(base, K8S_VERSIONS[0]), 'Service port "eighty" validated'


def test_semantic_rules_catch_a_broken_base(base):
    """A readiness probe on /healthz, a writable root and a PDB selecting nothing."""
    c = first(base, "Deployment")["spec"]["template"]["spec"]["containers"][0]
    c["readinessProbe"]["httpGet"]["path"] = "/healthz"
    c["securityContext"]["readOnlyRootFilesystem"] = False
    first(base, "PodDisruptionBudget")["spec"]["selector"]["matchLabels"]["app.kubernetes.io/name"] = "other"
    problems, _ = semantic_checks(base, universe_of(base), None)
    assert (len(problems) >= 3 and any("readinessProbe" in p for p in problems)
            and any("PodDisruptionBudget" in p for p in problems)
            and any("readOnlyRoot" in p for p in problems)), f"found only {problems}"


def broken_copy(rendered, *path: str) -> list[dict]:
    objs = rendered.get(k8s(*path))
    if not objs:
        pytest.skip(f"deploy/k8s/{'/'.join(path)} did not render")
    return copy.deepcopy(objs)


def test_semantic_rules_catch_parts_completions_8_against_16(rendered):
    """completions 8 against --part $(JOB_COMPLETION_INDEX)/16."""
    objs = broken_copy(rendered, "pyramid-build", "parts")
    first(objs, "Job")["spec"]["completions"] = 8
    problems, _ = semantic_checks(objs, universe_of(objs), None)
    assert any("completions 8" in p for p in problems), f"found {problems}"


def test_semantic_rules_catch_a_broken_load_job(rendered):
    """completions 4 against --shard $(JOB_COMPLETION_INDEX)/8, parallelism above it,
    per-index retries and one --out for all shards."""
    objs = broken_copy(rendered, "load", "replay")
    job = first(objs, "Job")
    job["spec"]["completions"] = 4
    job["spec"]["backoffLimitPerIndex"] = 1
    args = job["spec"]["template"]["spec"]["containers"][0]["args"]
    args[args.index("--out") + 1] = "/results"
    problems, _ = semantic_checks(objs, universe_of(objs), None)
    assert (any("completions 4" in p for p in problems) and any("parallelism" in p for p in problems)
            and any("rerun" in p for p in problems) and any("per shard" in p for p in problems)), \
        f"found {problems}"


def test_semantic_rules_catch_every_pod_replaying_shard_0(rendered):
    objs = broken_copy(rendered, "load", "replay")
    args = first(objs, "Job")["spec"]["template"]["spec"]["containers"][0]["args"]
    args[args.index("--shard") + 1] = "0/8"
    problems, _ = semantic_checks(objs, universe_of(objs), None)
    assert any("not $(JOB_COMPLETION_INDEX)" in p for p in problems), f"found {problems}"


def test_kustomize_refuses_a_kustomization_with_a_missing_resource(tmp_path):
    (tmp_path / "kustomization.yaml").write_text("resources: [missing.yaml]\n")
    with pytest.raises(RenderError, match="missing.yaml"):
        render(str(tmp_path))
