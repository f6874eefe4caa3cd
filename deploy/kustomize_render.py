#!/usr/bin/env python3
"""A small Kustomize renderer for deploy/k8s/, so CI needs neither kubectl nor kustomize.

It implements only what deploy/k8s uses, and refuses anything else (an unknown
kustomization field, a patch directive, a JSON 6902 patch...) with an error rather than
rendering something different from `kubectl kustomize`:

- `resources`: YAML files (several documents each) and directories with their own
  kustomization (rendered first, recursively);
- `components` (kind: Component): their resources are added and their transformations
  applied to everything accumulated so far;
- `namespace`: set on every namespaced object;
- `labels` (pairs, includeSelectors, includeTemplates) -- `commonLabels` is refused;
- `commonAnnotations`;
- `images` (name, newName, newTag, digest) in containers, initContainers and
  ephemeralContainers anywhere in an object;
- `patches` (path or inline patch, optional target by kind/name/namespace): strategic
  merge with Kubernetes' merge keys for the lists that have one (containers by name,
  env by name, volumes by name, volumeMounts by mountPath, container ports by
  containerPort, service ports by port, ...), other lists replaced, `null` deletes.

Transformations run in kustomize's order: patches, namespace, labels, annotations,
images. Output is kustomize's "legacy" order (Namespace first, ... Deployment, ...).
deploy/check.sh compares this renderer's output with `kubectl kustomize` whenever
kubectl is installed.

    python3 deploy/kustomize_render.py DIR        # prints the rendered YAML stream
"""

from __future__ import annotations

import copy
import os
import sys

import yaml


class RenderError(Exception):
    pass


KUSTOMIZATION_FILES = ("kustomization.yaml", "kustomization.yml", "Kustomization")
SUPPORTED_FIELDS = {
    "apiVersion",
    "kind",
    "metadata",
    "resources",
    "components",
    "namespace",
    "labels",
    "commonAnnotations",
    "images",
    "patches",
}

# Kinds that are not namespaced (the ones a deployment is likely to carry).
CLUSTER_SCOPED = {
    "Namespace",
    "ClusterRole",
    "ClusterRoleBinding",
    "CustomResourceDefinition",
    "PersistentVolume",
    "StorageClass",
    "PriorityClass",
    "IngressClass",
    "RuntimeClass",
    "CSIDriver",
    "APIService",
    "MutatingWebhookConfiguration",
    "ValidatingWebhookConfiguration",
    "ValidatingAdmissionPolicy",
    "ValidatingAdmissionPolicyBinding",
}

# Kustomize's legacy output order.
ORDER_FIRST = [
    "Namespace",
    "ResourceQuota",
    "StorageClass",
    "CustomResourceDefinition",
    "ServiceAccount",
    "PodSecurityPolicy",
    "Role",
    "ClusterRole",
    "RoleBinding",
    "ClusterRoleBinding",
    "ConfigMap",
    "Secret",
    "Endpoints",
    "Service",
    "LimitRange",
    "PriorityClass",
    "PersistentVolume",
    "PersistentVolumeClaim",
    "Deployment",
    "StatefulSet",
    "CronJob",
    "PodDisruptionBudget",
]
ORDER_LAST = ["MutatingWebhookConfiguration", "ValidatingWebhookConfiguration"]

# Where `labels: includeTemplates` (and includeSelectors) put labels on pod templates.
TEMPLATE_LABEL_PATHS = {
    "Deployment": [["spec", "template", "metadata", "labels"]],
    "ReplicaSet": [["spec", "template", "metadata", "labels"]],
    "ReplicationController": [["spec", "template", "metadata", "labels"]],
    "DaemonSet": [["spec", "template", "metadata", "labels"]],
    "StatefulSet": [["spec", "template", "metadata", "labels"]],
    "Job": [["spec", "template", "metadata", "labels"]],
    "CronJob": [
        ["spec", "jobTemplate", "metadata", "labels"],
        ["spec", "jobTemplate", "spec", "template", "metadata", "labels"],
    ],
}
# Where `labels: includeSelectors: true` puts them besides (only the simple cases; a
# selector inside affinity or topologySpreadConstraints is refused, see _labels).
SELECTOR_LABEL_PATHS = {
    "Service": [["spec", "selector"]],
    "ReplicationController": [["spec", "selector"]],
    "Deployment": [["spec", "selector", "matchLabels"]],
    "ReplicaSet": [["spec", "selector", "matchLabels"]],
    "DaemonSet": [["spec", "selector", "matchLabels"]],
    "StatefulSet": [["spec", "selector", "matchLabels"]],
    "PodDisruptionBudget": [["spec", "selector", "matchLabels"]],
}

# Strategic-merge keys of the lists deploy/k8s might patch (from the Kubernetes API's
# x-kubernetes-patch-merge-key). Other lists are replaced whole.
MERGE_KEYS = {
    "containers": "name",
    "initContainers": "name",
    "ephemeralContainers": "name",
    "env": "name",
    "volumes": "name",
    "volumeMounts": "mountPath",
    "volumeDevices": "devicePath",
    "imagePullSecrets": "name",
    "hostAliases": "ip",
    "topologySpreadConstraints": "topologyKey",
}


def _load_yaml_documents(path: str) -> list[dict]:
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


def _kustomization_path(directory: str) -> str:
    for name in KUSTOMIZATION_FILES:
        p = os.path.join(directory, name)
        if os.path.isfile(p):
            return p
    raise RenderError(f"{directory}: no kustomization.yaml")


def _key(obj: dict) -> tuple:
    meta = obj.get("metadata") or {}
    return (obj.get("apiVersion"), obj.get("kind"), meta.get("namespace"), meta.get("name"))


def _describe(obj: dict) -> str:
    meta = obj.get("metadata") or {}
    ns = meta.get("namespace")
    return f"{obj.get('kind')}/{meta.get('name')}" + (f" (namespace {ns})" if ns else "")


def render(directory: str, _stack: tuple = ()) -> list[dict]:
    """Renders the kustomization in `directory`; returns the objects in legacy order."""
    directory = os.path.normpath(directory)
    if directory in _stack:
        raise RenderError(f"{directory}: cycle through {' -> '.join(_stack)}")
    objs = _build(directory, _stack + (directory,), expect_kind="Kustomization")
    return sort_legacy(objs)


def _build(directory: str, stack: tuple, expect_kind: str) -> list[dict]:
    kpath = _kustomization_path(directory)
    docs = _load_yaml_documents(kpath)
    if len(docs) != 1:
        raise RenderError(f"{kpath}: expected one document")
    k = docs[0]
    kind = k.get("kind", "Kustomization")
    if kind != expect_kind:
        raise RenderError(f"{kpath}: kind is {kind}, expected {expect_kind}")
    unknown = set(k) - SUPPORTED_FIELDS
    if unknown:
        raise RenderError(
            f"{kpath}: fields this renderer does not implement: {', '.join(sorted(unknown))}"
            " (extend deploy/kustomize_render.py, and check it against kubectl kustomize)"
        )

    objs: list[dict] = []
    for res in k.get("resources") or []:
        p = os.path.normpath(os.path.join(directory, res))
        if os.path.isdir(p):
            if p in stack:
                raise RenderError(f"{kpath}: resource {res} makes a cycle")
            objs.extend(_build(p, stack + (p,), expect_kind="Kustomization"))
        elif os.path.isfile(p):
            for d in _load_yaml_documents(p):
                for f in ("apiVersion", "kind"):
                    if f not in d:
                        raise RenderError(f"{p}: an object has no {f}")
                if not (d.get("metadata") or {}).get("name"):
                    raise RenderError(f"{p}: a {d['kind']} has no metadata.name")
                objs.append(d)
        else:
            raise RenderError(f"{kpath}: resource {res} does not exist")

    seen = {}
    for o in objs:
        if _key(o) in seen:
            raise RenderError(f"{kpath}: {_describe(o)} is defined twice")
        seen[_key(o)] = o

    for comp in k.get("components") or []:
        p = os.path.normpath(os.path.join(directory, comp))
        if not os.path.isdir(p):
            raise RenderError(f"{kpath}: component {comp} is not a directory")
        # A component's resources join the set, then its transformations apply to all.
        objs = _apply_component(p, stack + (p,), objs)

    _transform(k, directory, kpath, objs)
    return objs


def _apply_component(directory: str, stack: tuple, objs: list[dict]) -> list[dict]:
    kpath = _kustomization_path(directory)
    k = _load_yaml_documents(kpath)[0]
    if k.get("kind") != "Component":
        raise RenderError(f"{kpath}: a component must have kind: Component")
    # Its own resources join the set, then its transformations apply to everything.
    added: list[dict] = []
    for res in k.get("resources") or []:
        p = os.path.normpath(os.path.join(directory, res))
        if os.path.isdir(p):
            added.extend(_build(p, stack + (p,), expect_kind="Kustomization"))
        else:
            added.extend(_load_yaml_documents(p))
    unknown = set(k) - SUPPORTED_FIELDS
    if unknown:
        raise RenderError(f"{kpath}: fields this renderer does not implement: {sorted(unknown)}")
    objs = objs + added
    for sub in k.get("components") or []:
        objs = _apply_component(os.path.normpath(os.path.join(directory, sub)), stack, objs)
    _transform(k, directory, kpath, objs)
    return objs


def _transform(k: dict, directory: str, kpath: str, objs: list[dict]) -> None:
    for patch in k.get("patches") or []:
        _apply_patch(patch, directory, kpath, objs)
    if k.get("namespace"):
        ns = k["namespace"]
        for o in objs:
            if o["kind"] in ("RoleBinding", "ClusterRoleBinding"):
                raise RenderError(f"{kpath}: namespace with role bindings is not implemented")
            if o["kind"] not in CLUSTER_SCOPED:
                o.setdefault("metadata", {})["namespace"] = ns
    for entry in k.get("labels") or []:
        _labels(entry, kpath, objs)
    if k.get("commonAnnotations"):
        for o in objs:
            ann = o.setdefault("metadata", {}).setdefault("annotations", {})
            ann.update({str(a): str(b) for a, b in k["commonAnnotations"].items()})
    for image in k.get("images") or []:
        _images(image, kpath, objs)


def _labels(entry: dict, kpath: str, objs: list[dict]) -> None:
    unknown = set(entry) - {"pairs", "includeSelectors", "includeTemplates"}
    if unknown:
        raise RenderError(f"{kpath}: labels fields not implemented: {sorted(unknown)}")
    pairs = {str(a): str(b) for a, b in (entry.get("pairs") or {}).items()}
    selectors = bool(entry.get("includeSelectors", False))
    templates = selectors or bool(entry.get("includeTemplates", False))
    for o in objs:
        o.setdefault("metadata", {}).setdefault("labels", {}).update(pairs)
        paths = []
        if templates:
            paths += TEMPLATE_LABEL_PATHS.get(o["kind"], [])
        if selectors:
            paths += SELECTOR_LABEL_PATHS.get(o["kind"], [])
            pod = (o.get("spec") or {}).get("template", {}).get("spec", {})
            if pod.get("affinity") or pod.get("topologySpreadConstraints"):
                raise RenderError(
                    f"{kpath}: includeSelectors on {_describe(o)}, whose affinity or "
                    "topology spread selectors kustomize would also change: not implemented"
                )
        for path in paths:
            node = o
            for part in path[:-1]:
                node = node.setdefault(part, {})
            node.setdefault(path[-1], {})
            if node[path[-1]] is None:
                node[path[-1]] = {}
            node[path[-1]].update(pairs)


def _split_image(image: str) -> tuple[str, str | None, str | None]:
    digest = None
    if "@" in image:
        image, digest = image.split("@", 1)
    tag = None
    slash = image.rfind("/")
    colon = image.rfind(":")
    if colon > slash:
        image, tag = image[:colon], image[colon + 1 :]
    return image, tag, digest


def _images(entry: dict, kpath: str, objs: list[dict]) -> None:
    unknown = set(entry) - {"name", "newName", "newTag", "digest"}
    if unknown:
        raise RenderError(f"{kpath}: images fields not implemented: {sorted(unknown)}")
    name = entry.get("name")
    if not name:
        raise RenderError(f"{kpath}: an images entry has no name")

    def visit(node):
        if isinstance(node, dict):
            for key, value in node.items():
                if key in ("containers", "initContainers", "ephemeralContainers") and isinstance(
                    value, list
                ):
                    for c in value:
                        if isinstance(c, dict) and isinstance(c.get("image"), str):
                            c["image"] = _retag(c["image"])
                visit(value)
        elif isinstance(node, list):
            for item in node:
                visit(item)

    def _retag(image: str) -> str:
        base, tag, digest = _split_image(image)
        if base != name:
            return image
        base = entry.get("newName", base)
        if "digest" in entry:
            return f"{base}@{entry['digest']}"
        if "newTag" in entry:
            return f"{base}:{entry['newTag']}"
        return base + (f":{tag}" if tag else "") + (f"@{digest}" if digest else "")

    for o in objs:
        visit(o)


def _apply_patch(entry: dict, directory: str, kpath: str, objs: list[dict]) -> None:
    unknown = set(entry) - {"path", "patch", "target", "options"}
    if unknown:
        raise RenderError(f"{kpath}: patches fields not implemented: {sorted(unknown)}")
    if entry.get("options"):
        raise RenderError(f"{kpath}: patch options are not implemented")
    if "path" in entry:
        docs = _load_yaml_documents(os.path.join(directory, entry["path"]))
        where = os.path.join(directory, entry["path"])
    elif "patch" in entry:
        try:
            docs = [d for d in yaml.safe_load_all(entry["patch"]) if d is not None]
        except yaml.YAMLError as e:
            raise RenderError(f"{kpath}: an inline patch is not valid YAML: {e}") from e
        where = f"{kpath} (inline patch)"
    else:
        raise RenderError(f"{kpath}: a patch needs path or patch")
    for doc in docs:
        if isinstance(doc, list):
            raise RenderError(f"{where}: JSON 6902 patches are not implemented")
        target = entry.get("target")
        if target:
            unknown = set(target) - {"kind", "name", "namespace", "group", "version"}
            if unknown:
                raise RenderError(f"{where}: target fields not implemented: {sorted(unknown)}")
            matches = [o for o in objs if _target_matches(o, target)]
        else:
            meta = doc.get("metadata") or {}
            matches = [
                o
                for o in objs
                if o.get("kind") == doc.get("kind")
                and (o.get("metadata") or {}).get("name") == meta.get("name")
                and (
                    "namespace" not in meta
                    or (o.get("metadata") or {}).get("namespace") == meta["namespace"]
                )
            ]
        if not matches:
            raise RenderError(f"{where}: the patch matches no object")
        for o in matches:
            patched = strategic_merge(o, doc, where)
            o.clear()
            o.update(patched)


def _target_matches(o: dict, target: dict) -> bool:
    meta = o.get("metadata") or {}
    group, _, version = (o.get("apiVersion") or "").rpartition("/")
    checks = {
        "kind": o.get("kind"),
        "name": meta.get("name"),
        "namespace": meta.get("namespace"),
        "group": group,
        "version": version,
    }
    return all(checks[f] == v for f, v in target.items())


def strategic_merge(base, patch, where: str, field: str | None = None):
    """Strategic merge of `patch` into a copy of `base` (see the module's docstring)."""
    if isinstance(patch, dict):
        for key in patch:
            if isinstance(key, str) and key.startswith("$"):
                raise RenderError(f"{where}: patch directive {key} is not implemented")
        if not isinstance(base, dict):
            return copy.deepcopy(patch)
        out = copy.deepcopy(base)
        for key, value in patch.items():
            if value is None:
                out.pop(key, None)
            elif key in out:
                out[key] = strategic_merge(out[key], value, where, key)
            else:
                out[key] = strategic_merge(None, value, where, key)
        return out
    if isinstance(patch, list):
        merge_key = MERGE_KEYS.get(field or "")
        if field == "ports":
            items = [i for i in patch + (base or []) if isinstance(i, dict)]
            merge_key = "containerPort" if any("containerPort" in i for i in items) else "port"
        if merge_key is None or not isinstance(base, list):
            return [strategic_merge(None, i, where) for i in patch]
        out = copy.deepcopy(base)
        new = []
        for item in patch:
            if not isinstance(item, dict) or merge_key not in item:
                raise RenderError(f"{where}: an item of {field} lacks its merge key {merge_key}")
            for i, existing in enumerate(out):
                if isinstance(existing, dict) and existing.get(merge_key) == item[merge_key]:
                    out[i] = strategic_merge(existing, item, where)
                    break
            else:
                new.append(strategic_merge(None, item, where))
        # Kustomize (kyaml) puts new list items first, in the patch's order.
        return new + out
    if isinstance(base, (dict, list)) or base is None:
        return copy.deepcopy(patch)
    return patch


def sort_legacy(objs: list[dict]) -> list[dict]:
    def rank(o):
        kind = o.get("kind")
        if kind in ORDER_FIRST:
            r = ORDER_FIRST.index(kind)
        elif kind in ORDER_LAST:
            r = len(ORDER_FIRST) + 1 + ORDER_LAST.index(kind)
        else:
            r = len(ORDER_FIRST)
        meta = o.get("metadata") or {}
        return (r, kind if r == len(ORDER_FIRST) else "", meta.get("namespace") or "", meta.get("name") or "")

    return sorted(objs, key=rank)


def dump(objs: list[dict]) -> str:
    return "---\n".join(yaml.safe_dump(o, sort_keys=True, default_flow_style=False) for o in objs)


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print("usage: kustomize_render.py DIR", file=sys.stderr)
        return 2
    try:
        sys.stdout.write(dump(render(argv[1])))
    except RenderError as e:
        print(f"kustomize_render: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
