#!/usr/bin/env bash
# A single-node Slurm cluster on this machine, for the tests and for trying `partition --slurm`
# without a cluster: its own munge key, config, state, spool and logs under DIR, no cgroups,
# one node with this machine's CPUs and a `gpu` generic resource (File=/dev/null: Slurm books
# it, nothing is bound), so `--gres=gpu:1` jobs run one at a time as on a one-GPU node.
#
#   scripts/slurm-node.sh start DIR   # prints the SLURM_CONF line to export, waits until idle
#   scripts/slurm-node.sh stop DIR    # stops the daemons it started
#
# Needs Debian's slurmctld, slurmd, slurm-client and munge (scripts/install-deps.sh installs
# them). Exits 3 when they are missing, 4 when the node does not come up (its logs printed).
set -euo pipefail

cmd=${1:?usage: slurm-node.sh start|stop DIR}
dir=${2:?usage: slurm-node.sh start|stop DIR}
mkdir -p "$dir"
dir=$(cd "$dir" && pwd)
conf="$dir/slurm.conf"

stop() {
  for pidfile in "$dir/slurmd.pid" "$dir/slurmctld.pid" "$dir/munge/munged.pid"; do
    if [ -f "$pidfile" ]; then
      pid=$(cat "$pidfile")
      kill "$pid" 2>/dev/null || true
      for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
      kill -9 "$pid" 2>/dev/null || true
      rm -f "$pidfile"
    fi
  done
}

if [ "$cmd" = stop ]; then
  stop
  exit 0
fi
[ "$cmd" = start ] || { echo "usage: slurm-node.sh start|stop DIR" >&2; exit 2; }

for b in munged slurmctld slurmd sbatch sinfo scontrol; do
  if ! command -v "$b" >/dev/null 2>&1 && ! [ -x "/usr/sbin/$b" ]; then
    echo "slurm-node: $b is not installed (Debian: apt-get install slurmctld slurmd slurm-client munge)" >&2
    exit 3
  fi
done
PATH="$PATH:/usr/sbin"

mkdir -p "$dir/munge" "$dir/state" "$dir/spool" "$dir/log"
chmod 700 "$dir/munge"
if [ ! -f "$dir/munge/munge.key" ]; then
  dd if=/dev/urandom of="$dir/munge/munge.key" bs=1024 count=1 status=none
  chmod 600 "$dir/munge/munge.key"
fi
# Ports: the test's own pair, away from a system Slurm's 6817/6818.
base=${SLURM_NODE_PORT:-$((20000 + RANDOM % 20000))}
host=$(hostname -s)
user=$(id -un)
cpus=$(nproc)
mem=$(awk '/MemTotal/ {print int($2 / 1024 * 0.8)}' /proc/meminfo)
cat > "$conf" <<EOF
ClusterName=lpmsplat-test
SlurmctldHost=$host(127.0.0.1)
SlurmUser=$user
SlurmdUser=$user
AuthType=auth/munge
AuthInfo=socket=$dir/munge/munge.socket
CredType=cred/munge
SlurmctldPort=$base
SlurmdPort=$((base + 1))
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/log/slurmctld.log
SlurmdLogFile=$dir/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU_Memory
MpiDefault=none
ReturnToService=2
SchedulerType=sched/builtin
MinJobAge=600
GresTypes=gpu
NodeName=$host NodeAddr=127.0.0.1 CPUs=$cpus RealMemory=$mem Gres=gpu:1 State=UNKNOWN
PartitionName=test Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
printf 'AutoDetect=off\nNodeName=%s Name=gpu File=/dev/null\n' "$host" > "$dir/gres.conf"

export SLURM_CONF="$conf"
munged -f --key-file="$dir/munge/munge.key" --socket="$dir/munge/munge.socket" \
  --pid-file="$dir/munge/munged.pid" --log-file="$dir/munge/munged.log" \
  --seed-file="$dir/munge/munge.seed"
slurmctld -f "$conf"
slurmd -f "$conf"

for _ in $(seq 100); do
  state=$(sinfo -h -n "$host" -o %T 2>/dev/null || true)
  if [ "$state" = idle ]; then
    echo "SLURM_CONF=$conf"
    exit 0
  fi
  sleep 0.3
done
echo "slurm-node: the node did not come up (state '${state:-none}'); logs:" >&2
tail -n 20 "$dir/log/slurmctld.log" "$dir/log/slurmd.log" "$dir/munge/munged.log" >&2 || true
stop
exit 4
