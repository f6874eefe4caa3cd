"""deploy/Dockerfile read as instructions, and this project's own rules for it
(LINT_RULES, on top of hadolint's)."""

from __future__ import annotations

import json
import re

from commands import arg_after
from deploy_paths import DOCKERFILE
from manifests import split_image


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


def image_args(ins: list[tuple[int, str, str]]) -> dict[str, str | None]:
    """The global ARGs (those before the first FROM, which FROM lines may use) and their
    defaults (None: no default)."""
    out: dict[str, str | None] = {}
    for _, instr, args in ins:
        if instr == "FROM":
            break
        if instr == "ARG":
            name, eq, default = args.partition("=")
            out[name.strip()] = default.strip().strip('"') if eq else None
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
D13 only the built binaries are copied from the builder
D14 every base image is a global `ARG NAME_IMAGE=<pinned default>` that its FROM names (local bases: deploy/image.py)"""


def lint_dockerfile(text: str) -> list[str]:
    problems = []
    ins = parse_dockerfile(text)
    first = text.lstrip().splitlines()[0] if text.strip() else ""
    if not re.match(r"#\s*syntax=docker/dockerfile:1(\.\d+)?\s*$", first):
        problems.append("D1: no `# syntax=docker/dockerfile:1.x` parser directive on line 1")
    global_args = image_args(ins)
    stages: list[dict] = []
    for line, instr, args in ins:
        if instr == "FROM":
            m = re.match(r"(?:--platform=\S+\s+)?(\S+)(?:\s+AS\s+(\S+))?$", args, re.I)
            if not m:
                problems.append(f"line {line}: D2: cannot parse FROM {args}")
                continue
            written = m.group(1)
            ref = re.fullmatch(r"\$\{?(\w+)\}?", written)
            image = global_args.get(ref.group(1)) if ref else written
            if ref and image is None:
                problems.append(f"line {line}: D14: FROM {written} names no global ARG with a default")
                image = written
            stages.append({"image": image, "written": written, "name": m.group(2), "ins": [], "line": line})
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
        if not re.fullmatch(r"\$\{?\w+_IMAGE\}?", s["written"]):
            problems.append(f"line {s['line']}: D14: FROM {s['written']} is not a global NAME_IMAGE build argument")
        base, tag, digest = split_image(img)
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
    """The final stage's ENTRYPOINT, CMD and HEALTHCHECK command (exec form), the
    packages its `apt-get install`s name, and the file's text."""
    with open(DOCKERFILE, encoding="utf-8") as f:
        text = f.read()
    ins = parse_dockerfile(text)
    last_from = max(i for i, (_, instr, _) in enumerate(ins) if instr == "FROM")
    final = ins[last_from:]
    out = {"text": text}
    out["apt_packages"] = []
    for _, instr, args in final:
        if instr == "RUN":
            # The packages of every `apt-get install` in the final stage.
            for m in re.finditer(r"apt-get install((?:\s+(?:-[\w-]+|[a-z0-9][\w.+-]*))+)", args):
                out["apt_packages"] += [w for w in m.group(1).split() if not w.startswith("-")]
        if instr in ("ENTRYPOINT", "CMD"):
            out[instr] = exec_form(args)
        if instr == "HEALTHCHECK":
            m = re.search(r"\bCMD\s+(.*)$", args)
            out["HEALTHCHECK"] = exec_form(m.group(1)) if m else None
    return out


if __name__ == "__main__":
    print(LINT_RULES)
