"""What the live fixtures record: the pyramids built, the servers started and what
they answered, for the tests to assert on; and the skip of a test whose prerequisite
failed."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from processes import Proc


def prerequisite(ok: bool, what: str) -> None:
    """Skips the test when what it builds on failed (that failure is reported by the
    test of `what`)."""
    if not ok:
        pytest.skip(f"{what} failed")


@dataclass
class Built:
    """A pyramid a build command wrote, and how the command went."""

    path: str
    ok: bool
    log: str
    seconds: float = 0.0
    what: str = ""


@dataclass
class Moto:
    """compose's `s3` service: moto_server on loopback."""

    proc: Proc
    endpoint: str
    up: bool


@dataclass
class Demo:
    """What build-demo's command wrote: `url` as compose names it, `local` the file that
    stands for it without S3."""

    url: str
    local: str
    has_s3: bool
    build: Built = field(default_factory=lambda: Built("", False, ""))

    def map(self, arg: str) -> str:
        return arg if self.has_s3 or arg != self.url else self.local


@dataclass
class Replica:
    """A compose replica's command started on loopback, and what it answered then."""

    name: str
    command: list
    proc: Proc
    url: str | None
    dataset_status: int = 0
    dataset_body: bytes = b""
    healthcheck_rc: int | None = None
