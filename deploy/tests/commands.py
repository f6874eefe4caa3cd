"""Reading and rewriting the command lines the manifests, the Dockerfile and
compose.yaml hold."""

from __future__ import annotations

def arg_after(args: list[str], flag: str) -> str | None:
    for i, a in enumerate(args):
        if a == flag and i + 1 < len(args):
            return args[i + 1]
        if a.startswith(flag + "="):
            return a[len(flag) + 1:]
    return None




def rewrite_listen(argv: list[str]) -> list[str]:
    """`argv` with its --listen address replaced by 127.0.0.1:0 (any free port)."""
    out = list(argv)
    for i, a in enumerate(out):
        if a == "--listen" and i + 1 < len(out):
            out[i + 1] = "127.0.0.1:0"
    return out


def port_of(url: str) -> int:
    return int(url.rsplit(":", 1)[1].rstrip("/"))


def unescape_compose(s: str) -> str:
    """compose.yaml's `$$` (a literal `$`, not interpolation) as the shell sees it."""
    return s.replace("$$", "$")
