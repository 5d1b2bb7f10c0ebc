#!/bin/bash
# A one-node Slurm cluster on this machine, everything in one folder, to try deploy/slurm
# without a cluster (and for crates/prt-cli/tests/slurm.rs). Needs root and Debian's slurm-wlm
# and munge (apt-get install slurm-wlm munge).
#
#   deploy/slurm/local-cluster.sh start DIR   # then: export SLURM_CONF=DIR/slurm.conf
#   deploy/slurm/local-cluster.sh stop DIR
#
# start writes the configuration (`conf DIR`: DIR/slurm.conf with cluster "prttest", node
# "prtnode" with this machine's CPUs and sockets as `slurmd -C` reports them, partition "prt",
# two free ports on 127.0.0.1; a fresh munge key), starts munged, slurmctld and slurmd with their
# state, spool, logs and PID files in DIR, and returns once the node is idle. stop cancels the
# cluster's jobs and ends the three daemons by the PIDs in their files (SIGTERM, SIGKILL after
# 10 s). `run DIR munged|slurmctld|slurmd` runs one daemon of a configured DIR in the
# foreground instead (the test starts them so, as its own children).
set -euo pipefail
usage() {
    echo "usage: $0 start|stop|conf DIR, or $0 run DIR munged|slurmctld|slurmd" >&2
    exit 2
}
[ "$#" -ge 2 ] || usage
action=$1
mkdir -p "$2"
dir=$(cd "$2" && pwd)
# slurm.conf cannot quote a path.
case $dir in *[[:space:]]*)
    echo "error: $dir has a space; pick a folder without" >&2
    exit 2
    ;;
esac
export PATH=$PATH:/usr/sbin:/usr/local/sbin SLURM_CONF=$dir/slurm.conf

# A port nothing on 127.0.0.1 answers on.
free_port() {
    local port
    while :; do
        port=$((20000 + RANDOM % 40000))
        if ! (exec 3<>"/dev/tcp/127.0.0.1/$port") 2>/dev/null; then
            echo "$port"
            return
        fi
    done
}

# Ends the process in PID file $1: SIGTERM, then SIGKILL after 10 s.
end() {
    [ -f "$1" ] || return 0
    local pid
    pid=$(cat "$1")
    if kill -TERM "$pid" 2>/dev/null; then
        # Gone, or a zombie that its parent has yet to reap.
        for _ in $(seq 100); do
            [ "$(cut -d' ' -f3 "/proc/$pid/stat" 2>/dev/null || echo Z)" = Z ] && break
            sleep 0.1
        done
        kill -KILL "$pid" 2>/dev/null || true
    fi
    rm -f "$1"
}

# Writes DIR's folders, munge key and slurm.conf.
configure() {
    mkdir -p "$dir/munge" "$dir/state" "$dir/spool/prtnode" "$dir/log"
    # munged refuses a key or a socket folder that others can read.
    chmod 700 "$dir" "$dir/munge"
    rm -f "$dir/munge/munge.key"
    head -c 1024 /dev/urandom >"$dir/munge/munge.key"
    chmod 400 "$dir/munge/munge.key"
    node=$(slurmd -C | head -1 | cut -d' ' -f2-)
    ctld_port=$(free_port)
    slurmd_port=$(free_port)
    while [ "$slurmd_port" = "$ctld_port" ]; do slurmd_port=$(free_port); done
    cat >"$SLURM_CONF" <<EOF
ClusterName=prttest
SlurmctldHost=localhost(127.0.0.1)
SlurmctldPort=$ctld_port
SlurmdPort=$slurmd_port
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$dir/munge/munge.socket
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool/%n
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/log/slurmctld.log
SlurmdLogFile=$dir/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
MpiDefault=none
ReturnToService=2
MinJobAge=600
NodeName=prtnode NodeAddr=127.0.0.1 $node
PartitionName=prt Nodes=prtnode Default=YES MaxTime=INFINITE State=UP
EOF
}

# Sets cmd to daemon $1's command line, in the foreground when $2 is "foreground".
daemon() {
    case $1 in
    munged)
        cmd=(munged --force --socket="$dir/munge/munge.socket" --key-file="$dir/munge/munge.key"
            --pid-file="$dir/munged.pid" --log-file="$dir/log/munged.log"
            --seed-file="$dir/munge/munged.seed")
        [ "$2" != foreground ] || cmd+=(--foreground)
        ;;
    slurmctld) cmd=(slurmctld -f "$SLURM_CONF") ;;
    slurmd) cmd=(slurmd -f "$SLURM_CONF" -N prtnode) ;;
    *) usage ;;
    esac
    case $1 in slurm*) [ "$2" != foreground ] || cmd+=(-D) ;; esac
}

case $action in
conf) configure ;;
run)
    [ "$#" -eq 3 ] || usage
    daemon "$3" foreground
    exec "${cmd[@]}"
    ;;
start)
    [ ! -f "$dir/slurmctld.pid" ] || { echo "error: a cluster runs in $dir ($0 stop $dir)" >&2; exit 1; }
    configure
    for name in munged slurmctld slurmd; do
        daemon "$name" background
        "${cmd[@]}"
    done
    for _ in $(seq 600); do
        [ "$(sinfo -h -N -o %T 2>/dev/null)" = idle ] && exit 0
        sleep 0.1
    done
    echo "error: the node is not idle after 60 s; logs in $dir/log" >&2
    exit 1
    ;;
stop)
    # Jobs first, so that no job step outlives slurmd.
    [ ! -f "$dir/slurmctld.pid" ] || scancel --user="$(id -un)" 2>/dev/null || true
    end "$dir/slurmd.pid"
    end "$dir/slurmctld.pid"
    end "$dir/munged.pid"
    ;;
*) usage ;;
esac
