#!/usr/bin/env bash
# A one-node Slurm on this machine (Debian 12: slurm-wlm 22.05 and munge), for tests/test_study_cluster.py's Slurm
# test and the docs' cluster commands: installs the packages if missing, writes /etc/slurm/slurm.conf for this host
# (all its CPUs, no cgroups, no accounting database), starts munged, slurmctld and slurmd unless they run, and checks
# that a job runs (srun hostname). As root. Fails loudly (exit 1, the daemons' log tails) when Slurm does not start.
# Usage: bin/slurm-local.sh          (idempotent; bin/slurm-local.sh stop ends the daemons it started)
set -euo pipefail
log() { printf '[slurm-local] %s\n' "$*"; }
die() { log "error: $*"; for f in /var/log/slurm/slurmctld.log /var/log/slurm/slurmd.log; do
  [ -f "$f" ] && { log "--- tail of $f"; tail -n 20 "$f"; }; done; exit 1; }

if [ "${1:-}" = stop ]; then   # the daemons this script started, by their pid files
  for f in /run/slurmd.pid /run/slurmctld.pid /run/munge/munged.pid; do
    pid=$(cat "$f" 2>/dev/null || true)
    [ -n "$pid" ] && kill "$pid" 2>/dev/null && log "stopped $(basename "$f" .pid) ($pid)"
  done
  exit 0
fi
[ "$(id -u)" = 0 ] || die "run as root (it installs packages and starts daemons)"
if ! command -v slurmctld >/dev/null || ! command -v munged >/dev/null; then
  log "installing slurm-wlm and munge"
  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq slurm-wlm munge >/dev/null
fi
host=$(hostname -s)
getent hosts "$host" >/dev/null || { log "adding $host to /etc/hosts"; echo "127.0.0.1 $host" >> /etc/hosts; }
cpus=$(nproc)
mem=$(awk '/MemTotal/ {print int($2 / 1024 * 0.9)}' /proc/meminfo)
mkdir -p /etc/slurm /var/spool/slurmctld /var/spool/slurmd /var/log/slurm /run/munge
chown slurm:slurm /var/spool/slurmctld /var/log/slurm 2>/dev/null || true
cat > /etc/slurm/slurm.conf <<CONF
# written by drs-torchrl bin/slurm-local.sh: a one-node cluster on $host
ClusterName=drs-local
SlurmctldHost=$host
SlurmUser=root
AuthType=auth/munge
StateSaveLocation=/var/spool/slurmctld
SlurmdSpoolDir=/var/spool/slurmd
SlurmctldPidFile=/run/slurmctld.pid
SlurmdPidFile=/run/slurmd.pid
SlurmctldLogFile=/var/log/slurm/slurmctld.log
SlurmdLogFile=/var/log/slurm/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
ReturnToService=2
MinJobAge=3600
KillWait=30
NodeName=$host CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=debug Nodes=$host Default=YES MaxTime=INFINITE State=UP OverSubscribe=NO
CONF
chown munge:munge /run/munge
pgrep -x munged >/dev/null || { log "starting munged"; runuser -u munge -- /usr/sbin/munged || die "munged did not start"; }
munge -n | unmunge >/dev/null || die "munge cannot encode and decode a credential"
pgrep -x slurmctld >/dev/null || { log "starting slurmctld"; /usr/sbin/slurmctld || die "slurmctld did not start"; }
pgrep -x slurmd >/dev/null || { log "starting slurmd"; /usr/sbin/slurmd || die "slurmd did not start"; }
for _ in $(seq 30); do
  state=$(sinfo -h -n "$host" -o %T 2>/dev/null || true)
  case "$state" in idle*|mixed*|allocated*) break ;; esac
  sleep 1
done
case "$state" in idle*|mixed*|allocated*) ;; *) die "node $host is '${state:-not listed}' after 30 s (sinfo)" ;; esac
out=$(timeout 60 srun -N1 -n1 -t 1 hostname 2>&1) || die "srun hostname failed: $out"
log "up: node $host ($cpus CPUs, ${mem} MB), partition debug; srun hostname -> $out"
