#!/usr/bin/env python3
"""Runs the workspace's test binaries several at a time (`./run test`'s cargo stage).

`cargo test` runs one test binary after another. Many of ours spend their time waiting
on sockets, servers and child processes (load replay, replicas, the CLI), not on the
CPU, so on a 2-core machine running a few binaries at once finishes sooner than
running them in turn. Each binary still runs its own tests the way `cargo test` does
(libtest's threads, the package directory as working directory, cargo's runtime
variables), so in-process fixtures are shared exactly as before.

Usage: tests/cargo_tests.py [--jobs N] [-- extra cargo args]

- The binaries are built first (`cargo test --no-run`, one compile), then run
  longest-first using the durations of the last run (kept in target/), so the slow
  ones do not start last.
- Each binary's output goes to a log; a failing binary's log is printed whole.
- The doc tests run last (`cargo test --doc`).
- Exit status: 0 when every binary and the doc tests pass, 1 otherwise.
"""

import argparse
import concurrent.futures
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def scope(extra):
    """The whole workspace, unless the extra arguments name packages (`-p NAME`)."""
    named = any(a in ("-p", "--package") or a.startswith("--package=") for a in extra)
    return list(extra) if named else ["--workspace", *extra]


def build(extra):
    """Compiles every test binary; returns [(name, executable, package dir, package)]."""
    cmd = ["cargo", "test", *scope(extra), "--locked", "--no-run", "--message-format=json-render-diagnostics"]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, text=True)
    binaries = []
    for line in proc.stdout:
        try:
            msg = json.loads(line)
        except json.JSONDecodeError:
            continue
        if msg.get("reason") != "compiler-artifact" or not msg.get("executable"):
            continue
        if not msg.get("profile", {}).get("test"):
            continue
        target = msg["target"]
        manifest = Path(msg["manifest_path"])
        package = msg["package_id"]
        # package_id is "path+file:///…/server#tessera-server@0.1.0" (or older forms):
        # the package's name is what cargo's runtime variables carry.
        name_part = package.split("#")[-1]
        pkg_name, _, version = name_part.partition("@")
        if not version:
            pkg_name = manifest.parent.name
        label = f"{pkg_name} {'/'.join(target['kind'])} {target['name']}"
        binaries.append((label, msg["executable"], manifest.parent, pkg_name, version))
    if proc.wait() != 0:
        sys.exit("cargo test --no-run failed (the errors are above)")
    return binaries


def run_one(binary, logs):
    label, exe, cwd, pkg, version = binary
    env = dict(os.environ)
    # What cargo sets when it runs a test binary itself.
    env.update(
        CARGO_MANIFEST_DIR=str(cwd),
        CARGO_PKG_NAME=pkg,
        CARGO_CRATE_NAME=pkg.replace("-", "_"),
        CARGO_PKG_VERSION=version or "0.0.0",
    )
    log = logs / (label.replace(" ", "_").replace("/", "-") + ".log")
    start = time.monotonic()
    with open(log, "w") as out:
        rc = subprocess.call([exe], cwd=cwd, env=env, stdout=out, stderr=subprocess.STDOUT)
    return label, rc, time.monotonic() - start, log


def summary(log):
    """The `test result:` line of a log, or its last line."""
    lines = log.read_text(errors="replace").splitlines()
    results = [l for l in lines if l.startswith("test result:")]
    return results[-1] if results else (lines[-1] if lines else "(no output)")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--jobs", type=int, default=int(os.environ.get("TESSERA_TEST_JOBS", "3")),
                    help="test binaries at once (default 3, or $TESSERA_TEST_JOBS)")
    ap.add_argument("extra", nargs="*", help="extra arguments for cargo (after --)")
    args = ap.parse_args()

    target = Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
    times_file = target / "test-binary-times.json"
    logs = target / "test-logs"
    logs.mkdir(parents=True, exist_ok=True)
    for old in logs.glob("*.log"):
        old.unlink()

    t0 = time.monotonic()
    binaries = build(args.extra)
    built = time.monotonic() - t0
    try:
        previous = json.loads(times_file.read_text())
    except (OSError, ValueError):
        previous = {}
    # Longest first; binaries never timed before go first of all (they may be slow).
    binaries.sort(key=lambda b: -previous.get(b[0], 1e9))
    print(f"== {len(binaries)} test binaries built in {built:.0f} s; running {args.jobs} at a time", flush=True)

    failed, times = [], {}
    t1 = time.monotonic()
    with concurrent.futures.ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        running = [pool.submit(run_one, b, logs) for b in binaries]
        for done in concurrent.futures.as_completed(running):
            label, rc, secs, log = done.result()
            times[label] = round(secs, 2)
            mark = "ok  " if rc == 0 else "FAIL"
            print(f"{mark} {secs:6.1f} s  {label}: {summary(log)}", flush=True)
            if rc != 0:
                failed.append((label, log))
    ran = time.monotonic() - t1
    times_file.write_text(json.dumps({**previous, **times}, indent=1, sort_keys=True))

    for label, log in failed:
        print(f"\n===== {label} failed; its output ({log}):", flush=True)
        print(log.read_text(errors="replace"), flush=True)

    t2 = time.monotonic()
    doc = subprocess.call(["cargo", "test", *scope(args.extra), "--locked", "--doc"], cwd=ROOT)
    docs = time.monotonic() - t2
    slowest = sorted(times.items(), key=lambda kv: -kv[1])[:5]
    print(f"== test binaries: {ran:.0f} s wall for {sum(times.values()):.0f} s of binaries "
          f"(slowest: {', '.join(f'{k} {v:.0f} s' for k, v in slowest)}); doc tests {docs:.0f} s", flush=True)
    if failed or doc != 0:
        names = ", ".join(label for label, _ in failed) or "(doc tests)"
        sys.exit(f"test failures: {names}")


if __name__ == "__main__":
    main()
