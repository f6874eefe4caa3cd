"""The distributed build's Jobs, run as Kubernetes would: the Indexed Job's command for
every JOB_COMPLETION_INDEX, then the assemble Job's, compared by content hash with a
single build; then part 3 removed (the assemble fails naming it) and its command rerun
alone (what backoffLimitPerIndex relies on). Only the input is shrunk (PARTS_SIZE)."""

from __future__ import annotations

import json
import os
import subprocess
import time
from dataclasses import dataclass, field

import pytest

from deploy_paths import PARTS_SIZE, k8s
from k8s_rules import container_env, expand, pod_spec
from outcomes import prerequisite
from processes import Proc, http_get, run


@dataclass
class BuildRun:
    parts_command: str = ""
    assemble_command: str = ""
    n: int = 0
    size: str = ""
    env: dict = field(default_factory=dict)
    part_failures: list = field(default_factory=list)
    part_times: list = field(default_factory=list)
    seconds: float = 0.0
    assemble: subprocess.CompletedProcess | None = None
    hash_single: str | None = None
    hash_assembled: str | None = None
    victim: str | None = None
    parts_listed: list = field(default_factory=list)
    assemble_without_part: subprocess.CompletedProcess | None = None
    rerun_log: str = ""
    hash_again: str | None = None


def content_hash(binary: str, path: str) -> str:
    return json.loads(run([binary, "info", path, "--json"]).stdout)["metadata"]["content_hash"]


@pytest.fixture(scope="module")
def build(rendered, has_s3, s3_env, demo, server_bin, live_tmp, base_env) -> BuildRun:
    prerequisite(demo.build.ok, "build-demo")  # the bucket exists, the build writes to S3
    s3 = s3_env if has_s3 else None
    objs = rendered.get(k8s("pyramid-build", "parts"), []) + rendered.get(k8s("pyramid-build", "assemble"), [])
    objects = {(o["kind"], o["metadata"]["name"]): o for o in objs}
    jobs = [o for o in objs if o["kind"] == "Job"]
    pj = next((j for j in jobs if j["spec"].get("completionMode") == "Indexed"), None)
    aj = next((j for j in jobs if j is not pj), None)
    if pj is None or aj is None:
        pytest.fail("the parts or the assemble Job is missing")
    pc, ac = pod_spec(pj)["containers"][0], pod_spec(aj)["containers"][0]
    r = BuildRun(" ".join(str(a) for a in pc["args"]), " ".join(str(a) for a in ac["args"]),
                 int(pj["spec"]["completions"]))
    env, _ = container_env(pc, objects)
    work = os.path.join(live_tmp, "work")
    os.makedirs(work)
    r.size = env["INPUT"]
    env["INPUT"] = PARTS_SIZE if r.size.startswith("synthetic:") else r.size
    env["PARTS"] = env["PARTS"].replace("/work", work, 1)
    assembled_local = os.path.join(live_tmp, "assembled.tess")
    if s3:
        env.update(s3)
        env["OUTPUT"] = "s3://tessera/assembled.tess"
    else:
        env["OUTPUT"] = assembled_local
    r.env = env

    # The parts, two at a time (the machine's cores).
    t0 = time.time()
    running: list = []
    todo = list(range(r.n))
    while todo or running:
        while todo and len(running) < 2:
            k = todo.pop(0)
            e = {**env, "JOB_COMPLETION_INDEX": str(k)}
            args = [expand(str(a), e) for a in pc["args"]]
            running.append((k, time.time(), subprocess.Popen([server_bin] + args + ["--quiet"], env={**base_env, **e},
                                                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)))
        time.sleep(0.05)
        for item in list(running):
            k, start, pr = item
            if pr.poll() is not None:
                running.remove(item)
                r.part_times.append(time.time() - start)
                if pr.returncode != 0:
                    r.part_failures.append(f"part {k}: {pr.stderr.read()[-300:]}")
    r.seconds = time.time() - t0
    if r.part_failures:
        return r

    e2, _ = container_env(ac, objects)
    e2.update({k: env[k] for k in ("INPUT", "PARTS", "OUTPUT")})
    if s3:
        e2.update(s3)
    args = [expand(str(a), e2) for a in ac["args"]]
    r.assemble = run([server_bin] + args + ["--quiet"], {**base_env, **e2})
    if r.assemble.returncode != 0:
        return r
    single = os.path.join(live_tmp, "single.tess")
    run([server_bin, "build", env["INPUT"], "-o", single, "--quiet"], base_env)
    r.hash_single = content_hash(server_bin, single)
    if s3:
        # Read back through the server: /v1/datasets/NAME tells the content hash.
        pr = Proc("assembled", [server_bin, "serve", env["OUTPUT"], "--listen", "127.0.0.1:0"],
                  {**base_env, **e2}, live_tmp)
        url = pr.wait_listening()
        st, _, body = http_get(f"{url}/v1/datasets/assembled") if url else (0, {}, b"")
        r.hash_assembled = json.loads(body).get("content_hash") if st == 200 else None
        pr.stop()
    else:
        r.hash_assembled = content_hash(server_bin, assembled_local)

    # Part 3's file removed: assembling fails naming it; index 3's command rerun by
    # itself, the assemble gives the same pyramid again.
    r.parts_listed = sorted(os.listdir(env["PARTS"]))
    r.victim = next((f for f in r.parts_listed if "0003" in f), None)
    if r.victim is None:
        return r
    os.remove(os.path.join(env["PARTS"], r.victim))
    local_out = os.path.join(live_tmp, "assembled-again.tess")
    e3 = {**e2, "OUTPUT": local_out}
    args = [expand(str(a), e3) for a in ac["args"]]
    r.assemble_without_part = run([server_bin] + args + ["--quiet"], {**base_env, **e3})
    e = {**env, "JOB_COMPLETION_INDEX": "3"}
    p = run([server_bin] + [expand(str(a), e) for a in pc["args"]] + ["--quiet"], {**base_env, **e})
    p2 = run([server_bin] + args + ["--quiet"], {**base_env, **e3}) if p.returncode == 0 else p
    r.rerun_log = (p2.stderr or p.stderr).strip()[-300:]
    if p2.returncode == 0:
        r.hash_again = content_hash(server_bin, local_out)
    return r


def assembled(build: BuildRun) -> BuildRun:
    prerequisite(not build.part_failures, "building the parts")
    prerequisite(build.assemble is not None and build.assemble.returncode == 0, "the assemble")
    return build


def with_part_3(build: BuildRun) -> BuildRun:
    assembled(build)
    if build.victim is None:
        pytest.fail(f"no part file named like part 3 among {build.parts_listed[:3]}...")
    return build


def test_indexed_job_command_builds_every_part(build):
    """`build $(INPUT) --part $(JOB_COMPLETION_INDEX)/16 -o $(PARTS)` for 0..15."""
    assert not build.part_failures, "; ".join(build.part_failures)
    print(f"`{build.parts_command}` for JOB_COMPLETION_INDEX 0..{build.n - 1} ({build.size} -> "
          f"{build.env['INPUT']}): {build.n} parts in {build.seconds:.1f} s, slowest {max(build.part_times):.1f} s")


def test_assemble_job_command_writes_the_pyramid(build):
    prerequisite(not build.part_failures, "building the parts")
    assert build.assemble.returncode == 0, f"`{build.assemble_command}`: {build.assemble.stderr[-500:]}"


def test_assembled_pyramid_has_the_single_builds_content_hash(build):
    b = assembled(build)
    assert b.hash_assembled == b.hash_single, f"assembled {b.hash_assembled}, single {b.hash_single}"


def test_assemble_fails_naming_a_missing_part(build):
    p = with_part_3(build).assemble_without_part
    assert p.returncode != 0 and ("0003" in p.stderr or "part 3" in p.stderr), \
        f"exit {p.returncode}: {p.stderr.strip()[-300:]}"


def test_part_rerun_alone_gives_the_same_pyramid(build):
    """What backoffLimitPerIndex relies on: a part that died is rerun by itself."""
    b = with_part_3(build)
    assert b.hash_again == b.hash_single, b.rerun_log
