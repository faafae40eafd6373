#!/usr/bin/env bash
# A private PostgreSQL 15 + PostGIS 3 server for the tests (Debian packages
# postgresql-15, postgresql-15-postgis-3): data folder and unix socket inside
# DIR, no TCP listener, trust authentication, one database `cityforge` with
# the postgis extension.
#
#   tools/pg/test_server.sh start DIR [PORT]   # prints the GDAL connection: PG:host=DIR port=PORT dbname=cityforge user=postgres
#   tools/pg/test_server.sh stop DIR           # stops the server and removes DIR
#
# As root (CI), the server runs as the `postgres` user (initdb refuses root).
set -euo pipefail
cmd="${1:?start|stop}"
dir="${2:?folder}"
port="${3:-54329}"
bin="${CITYFORGE_PG_BIN:-/usr/lib/postgresql/15/bin}"
as_server() {
  if [ "$(id -u)" -eq 0 ]; then runuser -u postgres -- "$@"; else "$@"; fi
}
case "$cmd" in
  start)
    [ -x "$bin/initdb" ] || { echo "test_server.sh: $bin/initdb not found (apt-get install postgresql-15 postgresql-15-postgis-3)" >&2; exit 1; }
    mkdir -p "$dir"
    if [ "$(id -u)" -eq 0 ]; then chown postgres "$dir"; fi
    as_server "$bin/initdb" -D "$dir/data" -A trust -U postgres -E UTF8 --no-sync >"$dir/initdb.log" 2>&1 ||
      { cat "$dir/initdb.log" >&2; exit 1; }
    as_server "$bin/pg_ctl" -D "$dir/data" -l "$dir/server.log" -w -t 60 \
      -o "-k $dir -c listen_addresses= -p $port -c fsync=off -c full_page_writes=off" start >/dev/null ||
      { cat "$dir/server.log" >&2; exit 1; }
    "$bin/createdb" -h "$dir" -p "$port" -U postgres cityforge
    "$bin/psql" -q -h "$dir" -p "$port" -U postgres -d cityforge -c "CREATE EXTENSION postgis" >/dev/null
    echo "PG:host=$dir port=$port dbname=cityforge user=postgres"
    ;;
  stop)
    if [ -f "$dir/data/postmaster.pid" ]; then as_server "$bin/pg_ctl" -D "$dir/data" -m immediate -w stop >/dev/null 2>&1 || true; fi
    rm -rf "$dir"
    ;;
  *)
    echo "usage: test_server.sh start|stop DIR [PORT]" >&2
    exit 2
    ;;
esac
