#!/usr/bin/env bash
# The Slurm path of `romunect dataset`, for real: starts a one-node Slurm cluster on this
# machine (munge, slurmctld and slurmd on localhost, every file in a temporary folder),
# submits scripts/slurm/dataset.sbatch as a 2-task array for a tiny dataset, waits (bounded),
# checks that the result equals a one-process run byte for byte, and stops the daemons.
# Installs Debian 12's slurm-wlm and munge when missing (root, or sudo).
#   scripts/slurm/ci_cluster.sh [build folder, default build]
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
build=${1:-$root/build}
romunect=$(cd "$build" 2>/dev/null && pwd)/bin/romunect
[ -x "$romunect" ] || { echo "slurm: no $romunect; build first" >&2; exit 1; }

sudo_cmd=()
if [ "$(id -u)" -ne 0 ]; then sudo_cmd=(sudo); fi
if ! command -v slurmctld >/dev/null || ! command -v munged >/dev/null; then
  echo "slurm: installing slurm-wlm and munge"
  export DEBIAN_FRONTEND=noninteractive
  "${sudo_cmd[@]}" apt-get update -q
  "${sudo_cmd[@]}" apt-get install -y -q --no-install-recommends slurm-wlm munge
fi
if [ "$(id -u)" -ne 0 ]; then echo "slurm: the daemons run as root here; run as root" >&2; exit 1; fi

tmp=$(mktemp -d /tmp/romunect-slurm.XXXXXX)
chmod 700 "$tmp"
stop() {
  for pidfile in "$tmp/slurmd.pid" "$tmp/slurmctld.pid" "$tmp/munged.pid"; do
    if [ -s "$pidfile" ]; then kill "$(cat "$pidfile")" 2>/dev/null || true; fi
  done
  sleep 1
  rm -rf "$tmp"
}
trap stop EXIT

# munge: its own key, socket and files, so a system munged (if any) is left alone
dd if=/dev/urandom of="$tmp/munge.key" bs=1024 count=1 status=none
chmod 400 "$tmp/munge.key"
munged --key-file="$tmp/munge.key" --socket="$tmp/munge.socket" --pid-file="$tmp/munged.pid" \
  --log-file="$tmp/munged.log" --seed-file="$tmp/munge.seed" --force

host=$(hostname -s)
node=$(slurmd -C | head -n 1)  # this machine's CPUs and memory, as slurmd detects them
mkdir -p "$tmp/state" "$tmp/spool"
cat > "$tmp/slurm.conf" <<CONF
ClusterName=romunect-ci
SlurmctldHost=$host(127.0.0.1)
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket=$tmp/munge.socket
CredType=cred/munge
SlurmctldPort=16817
SlurmdPort=16818
StateSaveLocation=$tmp/state
SlurmdSpoolDir=$tmp/spool
SlurmctldPidFile=$tmp/slurmctld.pid
SlurmdPidFile=$tmp/slurmd.pid
SlurmctldLogFile=$tmp/slurmctld.log
SlurmdLogFile=$tmp/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SwitchType=switch/none
MpiDefault=none
SchedulerType=sched/builtin
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
JobCompType=jobcomp/none
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
$node NodeAddr=127.0.0.1 State=UNKNOWN
PartitionName=ci Nodes=$host Default=YES MaxTime=10 State=UP
CONF
export SLURM_CONF=$tmp/slurm.conf
slurmctld -f "$SLURM_CONF"
slurmd -f "$SLURM_CONF"

# the node comes up within seconds
for _ in $(seq 60); do
  if sinfo -h -o %t 2>/dev/null | grep -qE '^(idle|mix|alloc)'; then break; fi
  sleep 1
done
sinfo -h -o '%P %t %c' | sed 's/^/slurm: partition, state, cpus: /'

tiny=(--scenes 3 --kinds pill_box,gear --objects 2-3 --variants 2 --views random --views-per-scene 2 --seed 5)
echo "slurm: a 2-task array for ${tiny[*]}"
ROMUNECT=$romunect timeout 600 sbatch --wait --array=0-1 --cpus-per-task=1 --output="$tmp/task-%a.log" \
  "$root/scripts/slurm/dataset.sbatch" "$tmp/sharded" "${tiny[@]}" || {
  echo "slurm: the array job failed" >&2
  cat "$tmp"/task-*.log "$tmp/slurmctld.log" "$tmp/slurmd.log" >&2 || true
  exit 1
}
"$romunect" dataset "$tmp/single" "${tiny[@]}" --quiet >/dev/null
if ! diff -r "$tmp/single" "$tmp/sharded" >/dev/null; then
  echo "slurm: the array's dataset differs from one process's" >&2
  diff -rq "$tmp/single" "$tmp/sharded" >&2 || true
  exit 1
fi
"$romunect" dataset check "$tmp/sharded"
echo "slurm: the 2-task array's dataset equals a one-process run byte for byte"
