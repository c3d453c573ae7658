#!/usr/bin/env bash
# Install (if needed) and start PostgreSQL on loopback for the sweep tests; idempotent and fast.
#
#   bash scripts/ci_postgres.sh            # then: export ASLEXP_TEST_POSTGRES_URL=... (printed)
#
# Debian packages via apt-get (run as root, as CI does here). Creates the role and database
# aslexp/aslexp_test (password aslexp) once; later calls only make sure the server is up.
# The server listens on 127.0.0.1 only. Prints the URL the tests use on its last line.
set -euo pipefail

PGUSER_NAME=${ASLEXP_PG_USER:-aslexp}
PGPASS_VALUE=${ASLEXP_PG_PASSWORD:-aslexp}
PGDB_NAME=${ASLEXP_PG_DB:-aslexp_test}
PGPORT_VALUE=${ASLEXP_PG_PORT:-5432}

as_root() { if [ "$(id -u)" -eq 0 ]; then "$@"; else sudo "$@"; fi; }

if ! command -v pg_lsclusters >/dev/null 2>&1 || [ -z "$(ls /usr/lib/postgresql 2>/dev/null)" ]; then
  echo "ci_postgres: installing PostgreSQL (Debian packages)"
  export DEBIAN_FRONTEND=noninteractive
  as_root apt-get update -qq
  as_root apt-get install -y -qq --no-install-recommends postgresql postgresql-client >/dev/null
fi

VERSION=$(ls /usr/lib/postgresql | sort -V | tail -1)
if ! pg_lsclusters -h | awk '{print $1" "$2}' | grep -qx "$VERSION main"; then
  echo "ci_postgres: creating cluster $VERSION/main"
  as_root pg_createcluster "$VERSION" main --port "$PGPORT_VALUE" >/dev/null
fi
CONF_DIR=/etc/postgresql/$VERSION/main
# Loopback only; the tests connect over TCP with a password.
if ! grep -q "^listen_addresses = '127.0.0.1'" "$CONF_DIR/postgresql.conf"; then
  echo "listen_addresses = '127.0.0.1'" | as_root tee -a "$CONF_DIR/postgresql.conf" >/dev/null
fi
if [ "$(pg_lsclusters -h | awk -v v="$VERSION" '$1==v && $2=="main" {print $4}')" != "online" ]; then
  echo "ci_postgres: starting cluster $VERSION/main"
  as_root pg_ctlcluster "$VERSION" main start
fi
for _ in $(seq 1 50); do
  pg_isready -q -h 127.0.0.1 -p "$PGPORT_VALUE" && break
  sleep 0.2
done
pg_isready -h 127.0.0.1 -p "$PGPORT_VALUE" >/dev/null || { echo "ci_postgres: server did not come up" >&2; exit 1; }

psql_admin() { as_root su postgres -c "psql -p $PGPORT_VALUE -v ON_ERROR_STOP=1 -qtA $*"; }
if [ "$(psql_admin "-c \"SELECT 1 FROM pg_roles WHERE rolname='$PGUSER_NAME'\"")" != "1" ]; then
  psql_admin "-c \"CREATE ROLE $PGUSER_NAME LOGIN PASSWORD '$PGPASS_VALUE' CREATEDB\""
fi
if [ "$(psql_admin "-c \"SELECT 1 FROM pg_database WHERE datname='$PGDB_NAME'\"")" != "1" ]; then
  psql_admin "-c \"CREATE DATABASE $PGDB_NAME OWNER $PGUSER_NAME\""
fi
echo "postgresql://$PGUSER_NAME:$PGPASS_VALUE@127.0.0.1:$PGPORT_VALUE/$PGDB_NAME"
