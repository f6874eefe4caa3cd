"""The load test's Jobs, run as Kubernetes would, with the `tessera` client against a
local server over the small pyramid: a trace recorded by 8 clients, every replay shard's
command (JOB_COMPLETION_INDEX 0..N-1, the volume's mount paths mapped to local folders,
all at once), then the merge Job's bash command, whose report must hold N shards and
their sums."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from dataclasses import dataclass, field

import pytest

from deploy_paths import SLIM_LIBRARIES, k8s
from k8s_rules import container_env, expand, pod_spec
from outcomes import prerequisite
from processes import Proc, linked_libraries, run


@dataclass
class LoadRun:
    server_url: str | None = None
    server_tail: str = ""
    dataset: str = ""
    trace_ok: bool = False
    trace_log: str = ""
    n: int = 0
    replay_command: str = ""
    shard_failures: list = field(default_factory=list)
    reports: list = field(default_factory=list)
    merge_command: str = ""
    merge: subprocess.CompletedProcess | None = None
    merged: dict | None = None
    merged_file: bool = False


def local_argv(vol: str, c: dict, spec: dict, argv: list[str]) -> list[str]:
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


@pytest.fixture(scope="session")
def client(client_bin) -> str:
    if client_bin is None:
        pytest.skip("no tessera client binary (cargo build -p tessera-client): the load Jobs' commands were not run")
    return client_bin


@pytest.fixture(scope="module")
def load(client, rendered, small_pyramid, server_bin, live_tmp, base_env) -> LoadRun:
    prerequisite(small_pyramid.ok, "the small pyramid")
    if "--replay" not in run([client, "load", "--help"]).stdout:
        pytest.skip("this tessera client has no `load --replay`: the load Jobs' commands were not run")
    objs = rendered.get(k8s("load", "replay"), []) + rendered.get(k8s("load", "merge"), [])
    objects = {(o["kind"], o["metadata"]["name"]): o for o in objs}
    jobs = [o for o in objs if o["kind"] == "Job"]
    rj = next((j for j in jobs if j["spec"].get("completionMode") == "Indexed"), None)
    mj = next((j for j in jobs if j is not rj), None)
    if rj is None or mj is None:
        pytest.fail("the replay or the merge Job is missing")
    vol = os.path.join(live_tmp, "load-volume")
    r = LoadRun()
    srv = Proc("load-server", [server_bin, "serve", small_pyramid.path, "--listen", "127.0.0.1:0"], base_env, live_tmp)
    r.server_url = url = srv.wait_listening()
    r.server_tail = srv.tail()
    if url is None:
        return r
    rspec = pod_spec(rj)
    rc = rspec["containers"][0]
    env, _ = container_env(rc, objects)
    # The Job's load, shrunk: 2 s at 40 requests/s in all against the local server.
    env.update({"SERVER": url, "RATE": "40", "DURATION": "2s"})
    claim_dir = os.path.join(vol, "tessera-load")
    os.makedirs(os.path.join(claim_dir, "trace"), exist_ok=True)
    os.makedirs(os.path.join(claim_dir, "results"), exist_ok=True)
    trace = os.path.join(claim_dir, "trace", "trace.jsonl")
    r.dataset = os.path.splitext(os.path.basename(small_pyramid.path))[0]
    p = run([client, "load", "--server", url, "--dataset", r.dataset, "--clients", "8", "--duration", "2s",
             "--record", trace, "--json"], base_env, timeout=120)
    r.trace_ok, r.trace_log = p.returncode == 0 and os.path.exists(trace), p.stderr[-500:]
    if not r.trace_ok:
        srv.stop()
        return r
    r.n = int(rj["spec"]["completions"])
    argv_k8s = [str(a) for a in (rc.get("command") or []) + (rc.get("args") or [])]
    r.replay_command = " ".join(argv_k8s)
    procs = []
    for k in range(r.n):
        e = {**env, "JOB_COMPLETION_INDEX": str(k)}
        argv = local_argv(vol, rc, rspec, [expand(a, e) for a in argv_k8s])
        argv[0] = client if argv[0] == "tessera" else argv[0]
        procs.append((k, subprocess.Popen(argv, env={**base_env, **e}, stdout=subprocess.PIPE,
                                          stderr=subprocess.PIPE, text=True)))
    for k, pr in procs:
        _out, err = pr.communicate(timeout=120)
        path = os.path.join(claim_dir, "results", str(k), "load.json")
        if pr.returncode != 0 or not os.path.exists(path):
            r.shard_failures.append(f"shard {k}: exit {pr.returncode}: {err.strip()[-300:]}")
        else:
            with open(path, encoding="utf-8") as f:
                r.reports.append(json.load(f))
    mspec = pod_spec(mj)
    mc = mspec["containers"][0]
    bindir = os.path.join(live_tmp, "load-bin")
    os.makedirs(bindir, exist_ok=True)
    if not os.path.exists(os.path.join(bindir, "tessera")):
        os.symlink(client, os.path.join(bindir, "tessera"))
    argv_k8s = [str(a) for a in (mc.get("command") or []) + (mc.get("args") or [])]
    r.merge_command = " ".join(argv_k8s)
    r.merge = run(local_argv(vol, mc, mspec, argv_k8s),
                  {**base_env, "PATH": bindir + os.pathsep + base_env.get("PATH", "")})
    if r.merge.returncode == 0:
        try:
            r.merged = json.loads(r.merge.stdout)
        except json.JSONDecodeError:
            r.merged = None
    r.merged_file = os.path.exists(os.path.join(claim_dir, "results", "merged", "load.json"))
    srv.stop()
    return r


def test_client_links_only_what_debian_slim_has(client):
    """The image's client binary, like the server's, may link only what debian:12-slim
    has (wgpu loads the GPU drivers at run time, and `load` never asks for them)."""
    if not shutil.which("ldd"):
        pytest.skip("ldd is not installed")
    libs = linked_libraries(client)
    assert libs and libs <= SLIM_LIBRARIES, f"also {sorted(libs - SLIM_LIBRARIES)}"


def test_local_server_for_the_replay_starts(load):
    assert load.server_url is not None, load.server_tail


def test_trace_recorded_by_8_clients(load):
    """`tessera load --record` (8 clients, 2 s) over the small pyramid."""
    prerequisite(load.server_url is not None, "the local server")
    assert load.trace_ok, load.trace_log


def test_replay_job_command_writes_every_shards_report(load):
    """SERVER a local server, RATE 40, DURATION 2s: every shard writes results/K/load.json."""
    prerequisite(load.trace_ok, "recording the trace")
    assert not load.shard_failures, f"`{load.replay_command}`: " + "; ".join(load.shard_failures)


def test_merge_job_command_adds_the_shards(load):
    """The merged report (results/merged/load.json) holds N shards and their sum."""
    prerequisite(load.trace_ok, "recording the trace")
    total = sum(r.get("sent", 0) for r in load.reports)
    merged = load.merged
    assert (merged is not None and merged.get("shards") == load.n and merged.get("sent") == total and total > 0
            and load.merged_file), (
        f"`{load.merge_command}`: exit {load.merge.returncode}: {load.merge.stderr.strip()[-300:]}; merged "
        f"{json.dumps({k: merged.get(k) for k in ('shards', 'sent')}) if merged else None}, shards sent {total}")
