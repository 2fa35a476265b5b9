#!/usr/bin/env bash
# A single-node Slurm on this machine (Debian's slurmctld + slurmd + munge), private to one
# state directory: its own munge key and socket, its own slurm.conf (proctrack/linuxproc, no
# cgroups, no accounting database), free TCP ports on 127.0.0.1. Needs root (slurmd launches
# jobs as their user) and no systemd: the daemons are started directly.
#
#   bash scripts/slurm-local.sh install         # apt-get the packages if missing (idempotent)
#   bash scripts/slurm-local.sh start DIR       # start munged, slurmctld, slurmd; writes DIR/env
#   . DIR/env                                   # SLURM_CONF for sbatch, squeue, scontrol, ...
#   bash scripts/slurm-local.sh stop DIR        # cancel the jobs, stop the daemons (by pid file)
#
# Environment for `start`: SLURM_LOCAL_CPUS (CPUs of the node, default nproc),
# SLURM_LOCAL_TIMEOUT (seconds to wait for the node to come up, default 60).
set -euo pipefail

die() {
    echo "slurm-local: $*" >&2
    exit 1
}

install() {
    local need=()
    command -v munged >/dev/null 2>&1 || need+=(munge)
    command -v slurmctld >/dev/null 2>&1 || need+=(slurmctld)
    command -v slurmd >/dev/null 2>&1 || need+=(slurmd)
    command -v sbatch >/dev/null 2>&1 || need+=(slurm-client)
    if [ ${#need[@]} -gt 0 ]; then
        local sudo=""
        if [ "$(id -u)" -ne 0 ]; then sudo="sudo"; fi
        echo "slurm-local: installing ${need[*]} with apt-get"
        $sudo apt-get update -q
        $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -q "${need[@]}"
    fi
}

free_port() {
    python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}

# pid of a daemon from its pid file, if it runs
running_pid() {
    local f=$1 pid
    [ -s "$f" ] || return 1
    pid=$(cat "$f")
    [ -n "$pid" ] && kill -0 "$pid" 2>/dev/null && echo "$pid"
}

start() {
    local dir=$1
    [ "$(id -u)" -eq 0 ] || die "start needs root (slurmd runs the jobs as their submitting user)"
    install
    mkdir -p "$dir"
    dir=$(cd "$dir" && pwd)
    if running_pid "$dir/slurmctld.pid" >/dev/null || running_pid "$dir/munged.pid" >/dev/null; then
        die "$dir already holds a running instance (stop it first: slurm-local.sh stop $dir)"
    fi
    # munged refuses group- or world-writable directories on its paths
    chmod 0700 "$dir"
    mkdir -p "$dir/munge" "$dir/spool" "$dir/state" "$dir/log"
    chmod 0700 "$dir/munge" "$dir/spool" "$dir/state" "$dir/log"
    local key="$dir/munge/munge.key"
    if [ ! -s "$key" ]; then
        dd if=/dev/urandom of="$key" bs=1024 count=1 status=none
        chmod 0400 "$key"
    fi
    local sock="$dir/munge/munge.socket"
    munged --force --key-file="$key" --socket="$sock" --pid-file="$dir/munged.pid" --log-file="$dir/log/munged.log" --seed-file="$dir/munge/munged.seed" ||
        die "munged did not start (see $dir/log/munged.log)"
    local host cpus mem ctld_port d_port
    host=$(hostname -s)
    cpus=${SLURM_LOCAL_CPUS:-$(nproc)}
    mem=$(awk '/MemTotal/ { printf "%d", $2 / 1024 * 0.8 }' /proc/meminfo)
    ctld_port=$(free_port)
    d_port=$(free_port)
    while [ "$d_port" = "$ctld_port" ]; do d_port=$(free_port); done
    cat >"$dir/slurm.conf" <<EOF
# written by scripts/slurm-local.sh: a single-node cluster private to $dir
ClusterName=twistopt-local
SlurmctldHost=$host(127.0.0.1)
SlurmctldPort=$ctld_port
SlurmdPort=$d_port
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$sock
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool/slurmd-%n
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/log/slurmctld.log
SlurmdLogFile=$dir/log/slurmd.log
SlurmctldDebug=info
SlurmdDebug=info
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SwitchType=switch/none
MpiDefault=none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
JobRequeue=1
KillWait=5
MinJobAge=600
SlurmdTimeout=60
InactiveLimit=0
NodeName=$host NodeAddr=127.0.0.1 NodeHostname=$host CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=local Nodes=$host Default=YES MaxTime=INFINITE State=UP OverSubscribe=NO
EOF
    printf 'export SLURM_CONF=%q\n' "$dir/slurm.conf" >"$dir/env"
    export SLURM_CONF="$dir/slurm.conf"
    slurmctld -f "$SLURM_CONF" -i || die "slurmctld did not start (see $dir/log/slurmctld.log)"
    slurmd -f "$SLURM_CONF" -N "$host" || die "slurmd did not start (see $dir/log/slurmd.log)"
    local timeout=${SLURM_LOCAL_TIMEOUT:-60} t=0 state=""
    while :; do
        state=$(sinfo -h -N -n "$host" -o '%T' 2>/dev/null || true)
        # "idle*" (with the star) is a node that does not respond yet
        case "$state" in
            idle | mixed | allocated) break ;;
        esac
        t=$((t + 1))
        if [ "$t" -gt "$timeout" ]; then
            tail -n 20 "$dir/log/slurmctld.log" "$dir/log/slurmd.log" >&2 || true
            die "node $host not up after ${timeout} s (state '${state:-none}')"
        fi
        sleep 1
    done
    echo "slurm-local: node $host up ($cpus CPUs, ${mem} MB, slurmctld on port $ctld_port); . $dir/env to use it"
}

stop() {
    local dir=$1
    [ -d "$dir" ] || return 0
    if [ -f "$dir/slurm.conf" ] && running_pid "$dir/slurmctld.pid" >/dev/null; then
        SLURM_CONF="$dir/slurm.conf" scancel --user="$(id -un)" 2>/dev/null || true
        # let slurmd end the jobs' steps before it stops itself
        for t in $(seq 1 30); do
            [ -z "$(SLURM_CONF="$dir/slurm.conf" squeue -h -o %i 2>/dev/null)" ] && break
            sleep 0.5
        done
    fi
    local name pid t
    for name in slurmd slurmctld munged; do
        pid=$(running_pid "$dir/$name.pid") || continue
        kill -TERM "$pid" 2>/dev/null || true
        for t in $(seq 1 50); do
            kill -0 "$pid" 2>/dev/null || break
            sleep 0.2
        done
        if kill -0 "$pid" 2>/dev/null; then
            echo "slurm-local: $name ($pid) did not stop on SIGTERM, sending SIGKILL" >&2
            kill -KILL "$pid" 2>/dev/null || true
        fi
    done
    echo "slurm-local: stopped the instance in $dir"
}

case "${1:-}" in
    install) install ;;
    start | stop)
        [ -n "${2:-}" ] || die "usage: slurm-local.sh $1 DIR"
        "$1" "$2"
        ;;
    *) die "usage: slurm-local.sh install | start DIR | stop DIR" ;;
esac
