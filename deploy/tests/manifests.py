"""The Kubernetes manifests under deploy/k8s: their Kustomize directories, the files
each refers to, their rendering, and strict validation against Kubernetes' schemas."""

from __future__ import annotations

import functools
import os
import shutil
import subprocess
import sys

import yaml

from deploy_paths import DEPLOY, K8S_DIR

sys.path.insert(0, DEPLOY)
import kustomize_render as kr  # noqa: E402

RenderError = kr.RenderError
describe = kr._describe
split_image = kr._split_image
object_key = kr._key
load_yaml_documents = kr._load_yaml_documents


def kustomize_dirs() -> list[str]:
    """Every directory under deploy/k8s with a kustomization (not a Component)."""
    out = []
    for dirpath, _dirs, files in os.walk(K8S_DIR):
        if "kustomization.yaml" in files:
            with open(os.path.join(dirpath, "kustomization.yaml"), encoding="utf-8") as f:
                k = yaml.safe_load(f) or {}
            if k.get("kind", "Kustomization") == "Kustomization":
                out.append(dirpath)
    return sorted(out)


def referenced_files(directory: str) -> set[str]:
    """Every file a kustomization (recursively) refers to, itself included."""
    kpath = kr._kustomization_path(directory)
    with open(kpath, encoding="utf-8") as f:
        k = yaml.safe_load(f) or {}
    out = {os.path.normpath(kpath)}
    for res in (k.get("resources") or []) + (k.get("components") or []):
        p = os.path.normpath(os.path.join(directory, res))
        out |= referenced_files(p) if os.path.isdir(p) else {p}
    for patch in k.get("patches") or []:
        if "path" in patch:
            out.add(os.path.normpath(os.path.join(directory, patch["path"])))
    return out


def render(directory: str) -> list[dict]:
    """The objects `directory`'s kustomization renders to (RenderError if it cannot)."""
    return kr.render(directory)


def kubectl_render(directory: str) -> list[dict] | None:
    """`kubectl kustomize directory`'s objects, None without kubectl."""
    if not shutil.which("kubectl"):
        return None
    p = subprocess.run(
        ["kubectl", "kustomize", directory], capture_output=True, text=True, timeout=60
    )
    if p.returncode != 0:
        raise RuntimeError(p.stderr.strip())
    return [d for d in yaml.safe_load_all(p.stdout) if d]


def install_schema_cache() -> None:
    """kubernetes-validate reads a schema file per object: read each once."""
    import kubernetes_validate.utils as kvu

    if not hasattr(kvu.schema_contents, "cache_info"):
        kvu.schema_contents = functools.lru_cache(maxsize=None)(kvu.schema_contents)


def validate_objects(objs: list[dict], version: str) -> list[str]:
    """Strict validation (unknown fields are errors) against Kubernetes `version`'s
    schemas: one message per problem, none when all objects are valid."""
    import kubernetes_validate

    install_schema_cache()
    errors = []
    for o in objs:
        try:
            kubernetes_validate.validate(o, version, strict=True)
        except kubernetes_validate.ValidationError as e:
            path = ".".join(str(p) for p in e.path) or "(top)"
            errors.append(f"{describe(o)}: {path}: {e.message}")
        except kubernetes_validate.SchemaNotFoundError as e:
            errors.append(f"{describe(o)}: {e.message}")
    return errors
