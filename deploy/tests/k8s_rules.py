"""The rules a reviewer checks in rendered Kubernetes objects: Pod Security
"restricted", probes and ports, selectors, the HPA's target, $(VAR)s that resolve, the
build Jobs' parts and the load test's shards (deploy/README.md "What deploy/check.sh
checks"), and the helpers that read pods, containers and their environment."""

from __future__ import annotations

import re

from commands import arg_after
from manifests import describe, split_image


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


def expand(value: str, env: dict) -> str:
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
            env[e["name"]] = expand(str(e["value"]), env)
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


def semantic_checks(objs: list[dict], universe: dict, tessera_envs: set[str] | None) -> tuple[list[str], dict]:
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
            p(f"{describe(o)} lacks app.kubernetes.io/part-of: tessera")

    # Pod templates: Pod Security "restricted", images pinned, resources.
    for o in objs:
        spec = pod_spec(o)
        if spec is None:
            continue
        d = describe(o)
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
            base, tag, digest = split_image(image)
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
        d = describe(dep)
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
            p(f"{describe(svc)}: selector {sel} selects {len(targets)} Deployments' pods, not 1")
            continue
        names = {pt.get("name") for pt in pod_spec(targets[0])["containers"][0].get("ports") or []}
        numbers = {pt.get("containerPort") for pt in pod_spec(targets[0])["containers"][0].get("ports") or []}
        for pt in svc["spec"].get("ports") or []:
            if pt.get("targetPort") not in names | numbers:
                p(f"{describe(svc)}: targetPort {pt.get('targetPort')} is not a port of the pods")
    for pdb in by_kind.get("PodDisruptionBudget", []):
        sel = ((pdb.get("spec") or {}).get("selector") or {}).get("matchLabels") or {}
        targets = [dep for dep in deployments if sel and all(pod_labels(dep).get(k) == v for k, v in sel.items())]
        if len(targets) != 1:
            p(f"{describe(pdb)}: selector {sel} matches {len(targets)} Deployments' pods, not 1")
    for hpa in by_kind.get("HorizontalPodAutoscaler", []):
        ref = hpa["spec"].get("scaleTargetRef") or {}
        target = [dep for dep in deployments if dep["metadata"]["name"] == ref.get("name")]
        if hpa.get("apiVersion") != "autoscaling/v2":
            p(f"{describe(hpa)}: not autoscaling/v2")
        if ref.get("kind") != "Deployment" or ref.get("apiVersion") != "apps/v1" or not target:
            p(f"{describe(hpa)}: scaleTargetRef {ref} is not a Deployment of this set")
        if (hpa["spec"].get("minReplicas") or 1) < 2:
            p(f"{describe(hpa)}: minReplicas below 2 (one replica is no high availability)")
        metrics = hpa["spec"].get("metrics") or []
        if not any((m.get("resource") or {}).get("name") == "cpu" for m in metrics):
            p(f"{describe(hpa)}: does not scale on CPU")
        for dep in target:
            for c in pod_spec(dep)["containers"]:
                if "cpu" not in ((c.get("resources") or {}).get("requests") or {}):
                    p(f"{describe(hpa)}: CPU utilization needs a CPU request on {c['name']}")

    # Build Jobs (the load test's Jobs have rules of their own: load_job_problems).
    parts_outputs = {}
    for job in jobs:
        d = describe(job)
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
            parts_outputs.setdefault("assemble", []).append((d, expand(arg_after(args, "--assemble"), env)))
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
        parts_outputs.setdefault("parts", []).append((d, expand(arg_after(args, "-o"), env)))
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


def place(m: dict, vol: dict, path: str) -> str:
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
    d = describe(job)
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
        out.append((None, ("load-merge", place(*where, m.group(1)))))
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
    out.append((None, ("load-results", place(*where, parent))))
    return out
