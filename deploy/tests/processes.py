"""The processes the live tests start (servers, moto, nginx), the commands they run,
and the HTTP requests they send, all on loopback."""

from __future__ import annotations

import os
import re
import select
import signal
import socket
import subprocess
import time
import urllib.error
import urllib.request

from commands import unescape_compose


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def http_get(url: str, headers: dict | None = None, timeout: float = 10) -> tuple[int, dict, bytes]:
    """(status, headers with lower-case names, body); status 0 when nothing answered."""
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
        while time.time() < deadline:
            if self.p.poll() is not None:
                break
            r, _, _ = select.select([self.p.stdout], [], [], 0.2)
            if r:
                line = self.p.stdout.readline()
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
        cls.all.clear()


def linked_libraries(binary: str) -> set[str]:
    """The shared libraries `ldd` says `binary` loads."""
    return set(re.findall(r"^\s*(\S+\.so[.\d]*)", run(["ldd", binary]).stdout, re.M))


def linked_library_paths(binary: str) -> dict[str, str]:
    """The shared libraries `ldd` says `binary` loads, by name, with the file each
    resolves to (the name itself for the loader and the vDSO)."""
    out = {}
    for line in run(["ldd", binary]).stdout.splitlines():
        m = re.match(r"^\s*(\S+)(?:\s+=>\s+(\S+))?", line)
        if m:
            out[m.group(1)] = m.group(2) or m.group(1)
    return out


def package_owning(path: str) -> str | None:
    """The Debian package that installed `path` (merged /usr: either spelling)."""
    real = os.path.realpath(path)
    candidates = {path, real}
    for p in list(candidates):
        if p.startswith("/usr/"):
            candidates.add(p[len("/usr"):])
        elif p.startswith("/"):
            candidates.add("/usr" + p)
    for p in candidates:
        r = run(["dpkg-query", "-S", p])
        if r.returncode == 0 and ":" in r.stdout:
            return r.stdout.split(":")[0].strip()
    return None


def apt_closure(packages: list[str]) -> set[str]:
    """`packages` and everything they depend on (Depends and Pre-Depends, recursively)."""
    r = run(["apt-cache", "depends", "--recurse", "--no-recommends", "--no-suggests",
             "--no-conflicts", "--no-breaks", "--no-replaces", "--no-enhances", *packages])
    names = set(packages)
    for line in r.stdout.splitlines():
        line = line.strip().lstrip("|")
        if line.startswith(("Depends:", "PreDepends:", "Pre-Depends:")):
            line = line.split(":", 1)[1]
        name = line.strip().strip("<>").split(":")[0]
        if name and " " not in name:
            names.add(name)
    return names


def run(argv: list[str], env: dict | None = None, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(argv, env=env, capture_output=True, text=True, timeout=timeout)


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
