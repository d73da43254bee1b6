#!/usr/bin/env bash
# A one-node SLURM on this machine, to test the slurm profile (tests/test_slurm_cluster.py, CI).
#   bash workflow/profiles/slurm/local-cluster.sh start    # install if missing, start, wait for idle
#   bash workflow/profiles/slurm/local-cluster.sh status   # sinfo and the queue
#   bash workflow/profiles/slurm/local-cluster.sh stop     # stop what start started
# Needs root and apt (Debian/Ubuntu: slurmctld, slurmd, slurm-client, munge). It writes
# /etc/slurm/slurm.conf (refusing to replace one it did not write) and keeps state, logs, the job
# completion records and pid files under $LBMPIPE_SLURM_DIR (default /tmp/lbmpipe-slurm); no
# other host is touched. One partition `local` holds this machine's cores and memory.
# Job status: no accounting database (slurmdbd) is started; the profile asks the executor plugin
# to poll `squeue` (slurm-status-command: squeue), which needs finished jobs to stay visible for
# a while (MinJobAge = 600 s here). Finished jobs are recorded by jobcomp/filetxt in
# $LBMPIPE_SLURM_DIR/jobcomp.log (job id, name, state, time limit, start and end).
set -euo pipefail

DIR=${LBMPIPE_SLURM_DIR:-/tmp/lbmpipe-slurm}
CONF=/etc/slurm/slurm.conf
MARK="# written by lbmpipe local-cluster.sh"
PACKAGES=(slurmctld slurmd slurm-client munge)

die() { echo "local-cluster.sh: $*" >&2; exit 2; }

install_missing() {
    local missing=()
    command -v slurmctld >/dev/null || missing+=(slurmctld)
    command -v slurmd >/dev/null || missing+=(slurmd)
    command -v sbatch >/dev/null || missing+=(slurm-client)
    command -v munged >/dev/null || missing+=(munge)
    [ ${#missing[@]} -eq 0 ] && return 0
    command -v apt-get >/dev/null || die "SLURM is not installed (${missing[*]}) and apt-get is missing: install ${PACKAGES[*]}"
    echo "installing ${missing[*]} with apt-get"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -q >/dev/null || die "apt-get update failed"
    apt-get install -y -q --no-install-recommends "${missing[@]}" >/dev/null || die "apt-get install ${missing[*]} failed"
}

write_conf() {
    if [ -e "$CONF" ] && ! grep -qF "$MARK" "$CONF"; then
        die "$CONF exists and was not written by this script: this machine has its own SLURM; use it, or move the file away"
    fi
    local node host line
    host=$(hostname -s)
    # The node as slurmd sees it (CPUs, sockets, cores, threads, RealMemory in MB).
    line=$(slurmd -C | head -n1)
    node=${line#NodeName=* }
    mkdir -p "$DIR/state" "$DIR/spool" "$DIR/log" /etc/slurm
    cat > "$CONF" <<EOF
$MARK (state in $DIR); removed by its stop
ClusterName=lbmpipe
SlurmctldHost=$host(127.0.0.1)
SlurmUser=root
AuthType=auth/munge
StateSaveLocation=$DIR/state
SlurmdSpoolDir=$DIR/spool
SlurmctldPidFile=$DIR/slurmctld.pid
SlurmdPidFile=$DIR/slurmd.pid
SlurmctldLogFile=$DIR/log/slurmctld.log
SlurmdLogFile=$DIR/log/slurmd.log
# No cgroups (containers often lack a writable cgroup tree): processes tracked by parentage.
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
MpiDefault=none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
JobAcctGatherType=jobacct_gather/linux
JobCompType=jobcomp/filetxt
JobCompLoc=$DIR/jobcomp.log
AccountingStorageType=accounting_storage/none
# Finished jobs stay in squeue for 10 min: the plugin's squeue status polling reads them there.
MinJobAge=600
# Seconds between SIGTERM and SIGKILL at scancel or at the time limit: a simulation finishes its
# current sample interval and writes its checkpoint on SIGTERM; on a shared, overloaded test
# machine (load 20 on 2 cores) one interval took over 2 minutes, against SLURM's default 30 s.
KillWait=300
# Jobs that give no --mem get this much per CPU (not the whole node).
DefMemPerCPU=1000
ReturnToService=2
SlurmctldTimeout=30
SlurmdTimeout=60
NodeName=$host NodeAddr=127.0.0.1 $node State=UNKNOWN
PartitionName=local Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
}

start_munge() {
    if munge -n 2>/dev/null | unmunge >/dev/null 2>&1; then
        echo "munge: already running"
        return 0
    fi
    if [ ! -s /etc/munge/munge.key ]; then
        if command -v mungekey >/dev/null; then mungekey --create --force; else
            dd if=/dev/urandom of=/etc/munge/munge.key bs=1 count=1024 status=none; fi
        chown munge:munge /etc/munge/munge.key && chmod 400 /etc/munge/munge.key
    fi
    mkdir -p /run/munge /var/log/munge /var/lib/munge
    chown munge:munge /run/munge /var/log/munge /var/lib/munge
    runuser -u munge -- /usr/sbin/munged
    cp /run/munge/munged.pid "$DIR/munged.pid"
}

wait_idle() {
    local i state
    for i in $(seq 1 60); do
        state=$(sinfo -h -N -o %T 2>/dev/null | head -n1 || true)
        if [ "$state" = idle ] || [ "$state" = mixed ] || [ "$state" = allocated ]; then
            echo "node $(hostname -s): $state"
            return 0
        fi
        sleep 1
    done
    echo "the node did not become idle within 60 s (state: ${state:-none}); logs:" >&2
    tail -n 20 "$DIR/log/slurmctld.log" "$DIR/log/slurmd.log" >&2 || true
    return 1
}

start() {
    [ "$(id -u)" -eq 0 ] || die "needs root (it installs packages and starts munged, slurmctld, slurmd)"
    install_missing
    if [ -f "$DIR/slurmctld.pid" ] && kill -0 "$(cat "$DIR/slurmctld.pid")" 2>/dev/null; then
        echo "already running (pid files in $DIR)"
        wait_idle
        return
    fi
    mkdir -p "$DIR"
    write_conf
    start_munge
    slurmctld
    slurmd
    wait_idle
}

stop_pid() {  # stop_pid NAME: SIGTERM the pid in $DIR/NAME.pid, wait, then SIGKILL
    local f="$DIR/$1.pid" pid i
    [ -f "$f" ] || return 0
    pid=$(cat "$f")
    if kill -0 "$pid" 2>/dev/null; then
        kill "$pid"
        for i in $(seq 1 20); do kill -0 "$pid" 2>/dev/null || break; sleep 0.5; done
        kill -0 "$pid" 2>/dev/null && kill -9 "$pid"
        echo "stopped $1 ($pid)"
    fi
    rm -f "$f"
}

stop() {
    # Jobs still queued or running belong to this cluster only: cancel them before the daemons go.
    if [ -f "$DIR/slurmctld.pid" ] && command -v scancel >/dev/null; then
        scancel --user "$(id -un)" 2>/dev/null || true
    fi
    stop_pid slurmd
    stop_pid slurmctld
    stop_pid munged
    if [ -e "$CONF" ] && grep -qF "$MARK" "$CONF"; then rm -f "$CONF"; fi
}

case "${1:-}" in
    start) start ;;
    stop) stop ;;
    status) sinfo; squeue ;;
    *) echo "usage: $0 start|stop|status" >&2; exit 2 ;;
esac
