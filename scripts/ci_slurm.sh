#!/usr/bin/env bash
# Install (if needed) and start a real single-node Slurm cluster on loopback for the Slurm tests;
# idempotent and fast (running, answering daemons are left alone).
#
#   bash scripts/ci_slurm.sh        # then tests/platform/test_slurm.py runs on it
#
# Debian packages via apt-get (run as root, as CI does here): munge, slurmctld, slurmd, the
# client commands, and accounting (slurmdbd on a local MariaDB) as on real clusters: submitit
# learns a job's state from `sacct`, so without accounting a cancelled job is waited for for
# ever. One node (this host, 127.0.0.1) with all its CPUs in one partition `debug`, scheduled
# per core so that several 1-CPU jobs run at once. Everything listens on loopback only.
# Prints "slurm ready: ..." on its last line.
set -euo pipefail

as_root() { if [ "$(id -u)" -eq 0 ]; then "$@"; else sudo -n "$@"; fi; }

HOST=$(hostname -s)
CLUSTER=aslexp-ci
CONF=/etc/slurm/slurm.conf
DBD_CONF=/etc/slurm/slurmdbd.conf
STATE_DIR=/var/spool/slurmctld
SPOOL_DIR=/var/spool/slurmd
LOG_DIR=/var/log/slurm
DB_PASS=aslexp-ci

missing=0
for cmd in munged slurmctld slurmd slurmdbd sbatch mariadbd; do
  command -v "$cmd" >/dev/null 2>&1 || [ -x "/usr/sbin/$cmd" ] || missing=1
done
if [ "$missing" = 1 ]; then
  echo "ci_slurm: installing munge, Slurm and MariaDB (Debian packages)"
  export DEBIAN_FRONTEND=noninteractive
  as_root apt-get update -qq
  as_root apt-get install -y -qq --no-install-recommends munge slurmctld slurmd slurm-client \
    slurmdbd mariadb-server >/dev/null
fi

# Rewrite a config file when its content differs; returns 0 when it changed.
write_if_changed() {  # FILE MODE CONTENT
  if [ -f "$1" ] && [ "$(cat "$1")" = "$3" ]; then return 1; fi
  printf '%s\n' "$3" | as_root tee "$1" >/dev/null
  as_root chmod "$2" "$1"
  echo "ci_slurm: wrote $1"
}

# A daemon is identified by its pid file (never by name: other processes are not ours).
running() { [ -s "$1" ] && kill -0 "$(cat "$1")" 2>/dev/null; }
stop() {  # PIDFILE: stop that daemon and wait for it
  if running "$1"; then
    local pid; pid=$(cat "$1"); as_root kill "$pid" 2>/dev/null || true
    for _ in $(seq 1 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
  fi
}

# munge: a key, then the daemon (it authenticates every Slurm message).
if [ ! -s /etc/munge/munge.key ]; then
  as_root mungekey --create --force
fi
as_root mkdir -p /run/munge /var/log/munge /var/lib/munge
as_root chown munge:munge /etc/munge/munge.key /run/munge /var/log/munge /var/lib/munge
as_root chmod 0400 /etc/munge/munge.key
if ! munge -n 2>/dev/null | unmunge >/dev/null 2>&1; then
  echo "ci_slurm: starting munged"
  as_root runuser -u munge -- /usr/sbin/munged --force
  for _ in $(seq 1 50); do munge -n 2>/dev/null | unmunge >/dev/null 2>&1 && break; sleep 0.1; done
fi
munge -n | unmunge >/dev/null || { echo "ci_slurm: munged did not come up" >&2; exit 1; }

# slurm.conf first: every Slurm command, sacctmgr included, reads it.
CPUS=$(nproc)
MEM_MB=$(awk '/MemTotal/ {print int($2 / 1024 * 0.8)}' /proc/meminfo)
WANTED="# Written by aslexp scripts/ci_slurm.sh: a single-node cluster on loopback for tests.
ClusterName=${CLUSTER}
SlurmctldHost=${HOST}(127.0.0.1)
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
StateSaveLocation=${STATE_DIR}
SlurmdSpoolDir=${SPOOL_DIR}
SlurmctldPidFile=/run/slurmctld.pid
SlurmdPidFile=/run/slurmd.pid
SlurmctldLogFile=${LOG_DIR}/slurmctld.log
SlurmdLogFile=${LOG_DIR}/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
MpiDefault=none
SwitchType=switch/none
SchedulerType=sched/builtin
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/slurmdbd
AccountingStorageHost=127.0.0.1
ReturnToService=2
KillWait=5
MinJobAge=300
InactiveLimit=0
NodeName=${HOST} NodeAddr=127.0.0.1 CPUs=${CPUS} RealMemory=${MEM_MB} State=UNKNOWN
PartitionName=debug Nodes=${HOST} Default=YES MaxTime=INFINITE State=UP OverSubscribe=NO"
if write_if_changed "$CONF" 0644 "$WANTED"; then
  # A changed configuration needs fresh daemons.
  stop /run/slurmctld.pid
  stop /run/slurmd.pid
fi

# Accounting: MariaDB on its local socket only (no TCP), then slurmdbd on 127.0.0.1.
as_root mkdir -p /run/mysqld /etc/slurm "$STATE_DIR" "$SPOOL_DIR" "$LOG_DIR"
as_root chown mysql:mysql /run/mysqld
if ! mysqladmin ping --silent >/dev/null 2>&1; then
  echo "ci_slurm: starting MariaDB"
  as_root runuser -u mysql -- /usr/sbin/mariadbd --skip-networking \
    --socket=/run/mysqld/mysqld.sock >>"$LOG_DIR/mariadb.log" 2>&1 &
  for _ in $(seq 1 150); do mysqladmin ping --silent >/dev/null 2>&1 && break; sleep 0.1; done
fi
mysqladmin ping --silent >/dev/null 2>&1 || { echo "ci_slurm: MariaDB did not come up" >&2; exit 1; }
as_root mysql -e "CREATE USER IF NOT EXISTS 'slurm'@'localhost' IDENTIFIED BY '${DB_PASS}';
  GRANT ALL ON slurm_acct_db.* TO 'slurm'@'localhost';"

DBD_WANTED="# Written by aslexp scripts/ci_slurm.sh.
AuthType=auth/munge
DbdAddr=127.0.0.1
DbdHost=${HOST}
SlurmUser=root
StorageType=accounting_storage/mysql
StorageHost=localhost
StorageUser=slurm
StoragePass=${DB_PASS}
StorageLoc=slurm_acct_db
PidFile=/run/slurmdbd.pid
LogFile=${LOG_DIR}/slurmdbd.log"
if write_if_changed "$DBD_CONF" 0600 "$DBD_WANTED"; then
  stop /run/slurmdbd.pid
fi
dbd_up() { (exec 3<>/dev/tcp/127.0.0.1/6819) 2>/dev/null; }
if ! running /run/slurmdbd.pid; then
  echo "ci_slurm: starting slurmdbd"
  as_root /usr/sbin/slurmdbd
fi
for _ in $(seq 1 150); do dbd_up && break; sleep 0.1; done
dbd_up || { echo "ci_slurm: slurmdbd did not come up" >&2; tail -n 20 "$LOG_DIR/slurmdbd.log" >&2; exit 1; }
# The cluster must be known to the accounting database before slurmctld registers with it.
if ! sacctmgr -n -P list cluster format=cluster 2>/dev/null | grep -qx "$CLUSTER"; then
  as_root sacctmgr -i add cluster "$CLUSTER" >/dev/null
fi

# Daemons in the background (no systemd in containers); -i: ignore unreadable old state.
if ! running /run/slurmctld.pid; then
  echo "ci_slurm: starting slurmctld"
  as_root /usr/sbin/slurmctld -i
fi
if ! running /run/slurmd.pid; then
  echo "ci_slurm: starting slurmd"
  as_root /usr/sbin/slurmd
fi

ready() { sinfo -h -N -o "%T" 2>/dev/null | grep -Eq '^(idle|mixed|allocated)$'; }
for _ in $(seq 1 150); do ready && break; sleep 0.2; done
if ! ready; then
  # A node left DOWN by an earlier run (e.g. a killed slurmd) comes back with RESUME.
  as_root scontrol update NodeName="$HOST" State=RESUME 2>/dev/null || true
  for _ in $(seq 1 50); do ready && break; sleep 0.2; done
fi
ready || { echo "ci_slurm: the node did not become ready:" >&2; sinfo -N >&2 || true;
           tail -n 20 "$LOG_DIR/slurmctld.log" "$LOG_DIR/slurmd.log" >&2 || true; exit 1; }
echo "slurm ready: cluster $CLUSTER, node $HOST, $CPUS CPUs, partition debug, accounting on"
