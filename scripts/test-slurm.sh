#!/usr/bin/env bash
# Opt-in test: the README's Slurm job array (section `voxfmt batch`) on a real single-node Slurm cluster, with
# faults. Installs Debian's slurm-wlm and munge if missing (root), starts munged (if none runs), slurmctld and
# slurmd on private ports with a private slurm.conf (SLURM_CONF; /etc/slurm is not touched), makes 9 meshes
# (8 of CGAL's samples and one slow one: copies of CGAL's elk turned about one axis, all through each other), submits the README's job script with
# only sizes and paths replaced (3 shards into one output folder), kills the task of the slow mesh mid-bake and
# requeues it, then checks the assets, the manifests and that nothing was baked twice. Everything it started is
# stopped at exit. Safe to run again; a run left over (daemons, jobs) is stopped first.
#
#   bash scripts/test-slurm.sh [path/to/voxfmt]      (default: $BUILD_DIR/bin/voxfmt, BUILD_DIR=build)
#
# Environment: VOXFMT_SLURM_DIR (/tmp/voxfmt-slurm-test: config, state, logs, meshes, assets),
# VOXFMT_SLURM_PORT (16817; slurmd uses the next port), VOXFMT_SLURM_TIMEOUT (300 s for the whole array),
# VOXFMT_SLURM_FAULTS ("kill requeue"), VOXFMT_SLURM_MESHES (CGAL's meshes; default the build's copy, else the
# libcgal-demo archive). Faults, in order, each on the same task while it bakes the slow mesh:
#   kill     SIGKILL to every process of the task at once (what a node crash or the OOM killer leaves:
#            no clean-up), then `scontrol requeue` of the failed task;
#   requeue  `scontrol requeue` of the running task: Slurm's SIGTERM (then SIGKILL after KillWait), as on
#            preemption.
set -euo pipefail
cd "$(dirname "$0")/.."
START_SECONDS=$SECONDS

VOXFMT=${1:-${BUILD_DIR:-build}/bin/voxfmt}
WORK=${VOXFMT_SLURM_DIR:-/tmp/voxfmt-slurm-test}
PORT=${VOXFMT_SLURM_PORT:-16817}
ARRAY_TIMEOUT=${VOXFMT_SLURM_TIMEOUT:-300}
FAULTS=${VOXFMT_SLURM_FAULTS:-kill requeue}
FAULT_AFTER_MS=1500  # into the slow mesh's bake (about 5 s on one core)
SHARDS=3
PY=/usr/bin/python3

step() { printf '\n== %s\n' "$*"; }
now_ms() { local us=${EPOCHREALTIME//[!0-9]/}; echo $((us / 1000)); }
info() { printf '   %s\n' "$*"; }
fail() {
  printf '\ntest-slurm: FAILED: %s\n' "$*" >&2
  exit 1
}

[ "$(id -u)" = 0 ] || fail "run as root (installs packages, starts munged, slurmctld and slurmd)"
[ -x "$VOXFMT" ] || fail "$VOXFMT: no voxfmt executable (build first: bash scripts/build.sh, or pass its path)"
VOXFMT=$(realpath "$VOXFMT")
mkdir -p "$WORK"
WORK=$(realpath "$WORK")
SLURM_DIR=$WORK/slurm
CONF=$SLURM_DIR/slurm.conf
SHARED=$WORK/shared  # the cluster's shared file system: meshes, assets, job script and task logs
MESHES=$SHARED/meshes
ASSETS=$SHARED/assets
JOBS=$SHARED/jobs
CHECK=$WORK/check
# Every process this test starts (munged, the daemons, hence the job steps, the job scripts and voxfmt) carries
# this variable; the clean-up stops exactly those. The script itself does not export it.
MARKER=VOXFMT_SLURM_TEST=$WORK
export SLURM_CONF=$CONF

exec 9>"$WORK.lock"
flock -n 9 || fail "another scripts/test-slurm.sh runs on $WORK ($WORK.lock)"

# --- processes of this test --------------------------------------------------------------------------------------
our_pids() {  # [comm...]: pids carrying the marker, optionally only those with one of these names
  local p pid comm
  for p in /proc/[0-9]*; do
    pid=${p#/proc/}
    grep -qzxF "$MARKER" "$p/environ" 2>/dev/null || continue
    if [ $# -gt 0 ]; then
      comm=$(cat "$p/comm" 2>/dev/null) || continue
      case " $* " in *" $comm "*) ;; *) continue ;; esac
    fi
    echo "$pid"
  done
}
stop_pids() {  # SECONDS PID...: SIGTERM, then SIGKILL to those still alive after SECONDS
  local wait_s=$1 pid alive i
  shift
  [ $# -gt 0 ] || return 0
  kill -TERM "$@" 2>/dev/null || true
  for ((i = 0; i < wait_s * 10; i++)); do
    alive=()
    for pid in "$@"; do kill -0 "$pid" 2>/dev/null && alive+=("$pid"); done
    [ ${#alive[@]} -gt 0 ] || return 0
    sleep 0.1
  done
  info "still running after ${wait_s} s, SIGKILL: $(for pid in "${alive[@]}"; do
    printf '%s(%s) ' "$pid" "$(cat "/proc/$pid/comm" 2>/dev/null)"
  done)"
  kill -KILL "${alive[@]}" 2>/dev/null || true
}
controller_up() { [ -n "$(our_pids slurmctld)" ] && [[ $(timeout 5 scontrol ping 2>/dev/null) == *UP* ]]; }
stop_everything() {  # jobs first (their steps would outlive slurmd), then the daemons, then any straggler
  local jobs i
  if controller_up; then
    jobs=$(timeout 5 squeue -h -o %A 2>/dev/null | sort -u | tr '\n' ' ') || jobs=
    if [ -n "${jobs// /}" ]; then
      info "cancelling jobs: $jobs"
      # shellcheck disable=SC2086
      timeout 5 scancel $jobs 2>/dev/null || true
      for ((i = 0; i < 150; i++)); do
        [ -z "$(timeout 5 squeue -h 2>/dev/null)" ] && break
        sleep 0.1
      done
    fi
  fi
  # shellcheck disable=SC2046
  stop_pids 10 $(our_pids slurmd slurmctld)
  # shellcheck disable=SC2046
  stop_pids 5 $(our_pids | grep -vxF -f <(our_pids munged) || true)
  # shellcheck disable=SC2046
  stop_pids 5 $(our_pids munged)
}
on_exit() {
  local status=$?
  trap - EXIT INT TERM
  step "stopping what this test started"
  stop_everything
  wait 2>/dev/null || true
  local left
  left=$(our_pids | tr '\n' ' ')
  if [ -n "$left" ]; then
    printf 'test-slurm: FAILED: processes of this test survived: %s\n' "$left" >&2
    status=1
  else
    info "nothing of this test is running"
  fi
  [ -z "${RESULT:-}" ] || echo "$RESULT"
  exit "$status"
}

# --- 1. packages -------------------------------------------------------------------------------------------------
step "packages: slurm-wlm, munge"
missing=()
for pkg in slurm-wlm munge; do
  [ "$(dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null)" = "install ok installed" ] || missing+=("$pkg")
done
if [ ${#missing[@]} -gt 0 ]; then
  info "installing ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  { apt-get update -qq && apt-get install -y -qq --no-install-recommends "${missing[@]}"; } >"$WORK/apt.log" 2>&1 ||
    { cat "$WORK/apt.log" >&2; fail "apt-get could not install ${missing[*]}"; }
else
  info "installed: $(dpkg-query -W -f='slurm-wlm ${Version}' slurm-wlm), $(dpkg-query -W -f='munge ${Version}' munge)"
fi
for tool in slurmctld slurmd sbatch squeue scontrol scancel sinfo munged munge unmunge; do
  command -v "$tool" >/dev/null || fail "$tool not found after installing slurm-wlm and munge"
done

# --- 2. cluster ---------------------------------------------------------------------------------------------------
step "single-node cluster in $SLURM_DIR"
left=$(our_pids | tr '\n' ' ')
if [ -n "$left" ]; then
  info "a previous run left processes behind: $(for pid in $left; do
    printf '%s(%s) ' "$pid" "$(cat "/proc/$pid/comm" 2>/dev/null)"
  done)- stopping them"
  stop_everything
fi
trap on_exit EXIT
trap 'exit 130' INT
trap 'exit 143' TERM

for port in "$PORT" $((PORT + 1)); do
  if ss -Hltn "sport = :$port" | grep -q .; then
    fail "port $port is in use (not by this test): set VOXFMT_SLURM_PORT to a free pair of ports"
  fi
done

if [ ! -s /etc/munge/munge.key ]; then
  info "creating a munge key"
  mungekey --create --keyfile=/etc/munge/munge.key
  chown munge:munge /etc/munge/munge.key
  chmod 0400 /etc/munge/munge.key
fi
if munge -n </dev/null 2>/dev/null | unmunge >/dev/null 2>&1; then
  info "munged: already running (left running)"
else
  info "munged: starting"
  install -d -o munge -g munge -m 0755 /run/munge
  env "$MARKER" setpriv --reuid=munge --regid=munge --clear-groups munged --foreground \
    >"$WORK/munged.log" 2>&1 9>&- &
  for ((i = 0; ; i++)); do
    munge -n </dev/null 2>/dev/null | unmunge >/dev/null 2>&1 && break
    [ "$i" -lt 100 ] || { cat "$WORK/munged.log" >&2; fail "munged did not start"; }
    sleep 0.1
  done
fi

hardware=$(slurmd -C)
CPUS=$(sed -n 's/.*CPUs=\([0-9]*\).*/\1/p' <<<"$hardware")
MEMORY=$(sed -n 's/.*RealMemory=\([0-9]*\).*/\1/p' <<<"$hardware")
{ [ -n "$CPUS" ] && [ -n "$MEMORY" ]; } || fail "cannot read CPUs and RealMemory from 'slurmd -C': $hardware"
info "this machine (slurmd -C): CPUs=$CPUS RealMemory=$MEMORY MiB"
[ "$MEMORY" -ge 2048 ] || fail "the job script asks 2 GB per task; this machine has $MEMORY MiB"

rm -rf "$SLURM_DIR" "$SHARED" "$CHECK"
mkdir -p "$SLURM_DIR"/{state,spool,log,run} "$MESHES" "$ASSETS" "$JOBS" "$CHECK"
cat >"$CONF" <<EOF
# Written by scripts/test-slurm.sh: one node (this machine), no cgroups, no accounting database.
ClusterName=voxfmt-test
SlurmctldHost=localhost(127.0.0.1)
SlurmctldPort=$PORT
SlurmdPort=$((PORT + 1))
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
# A requeued job waits cred_expire seconds before it may start again (default 120).
AuthInfo=cred_expire=10
StateSaveLocation=$SLURM_DIR/state
SlurmdSpoolDir=$SLURM_DIR/spool
SlurmctldPidFile=$SLURM_DIR/run/slurmctld.pid
SlurmdPidFile=$SLURM_DIR/run/slurmd.pid
SlurmctldLogFile=$SLURM_DIR/log/slurmctld.log
SlurmdLogFile=$SLURM_DIR/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/filetxt
JobCompLoc=$SLURM_DIR/log/jobcomp.log
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU_Memory
SchedulerType=sched/backfill
# Start a requeued task soon after it is eligible (the main and backfill loops run every 60 and 30 s by default).
SchedulerParameters=sched_interval=2,bf_interval=2
MpiDefault=none
MailProg=/bin/true
ReturnToService=2
JobRequeue=1
KillWait=5
NodeName=localhost NodeAddr=127.0.0.1 CPUs=$CPUS RealMemory=$MEMORY State=UNKNOWN
PartitionName=test Nodes=localhost Default=YES MaxTime=INFINITE State=UP
EOF
env "$MARKER" slurmctld -D -c -f "$CONF" >"$SLURM_DIR/log/slurmctld.out" 2>&1 9>&- &
env "$MARKER" slurmd -D -N localhost -f "$CONF" >"$SLURM_DIR/log/slurmd.out" 2>&1 9>&- &
daemon_logs() {
  local f
  for f in "$SLURM_DIR"/log/slurmctld.log "$SLURM_DIR"/log/slurmd.log "$SLURM_DIR"/log/*.out; do
    [ -s "$f" ] || continue
    printf -- '--- %s (last 25 lines)\n' "$f" >&2
    tail -n 25 "$f" >&2
  done
}
for ((i = 0; ; i++)); do
  state=$(timeout 5 sinfo -h -n localhost -o %T 2>/dev/null || true)
  [ "$state" = idle ] && break
  if [ "$i" -ge 300 ]; then
    daemon_logs
    fail "the node is not idle after 30 s (sinfo: '${state:-no answer}'); daemon logs above"
  fi
  sleep 0.1
done
info "slurmctld and slurmd up on ports $PORT, $((PORT + 1)); sinfo: $(sinfo -h -o '%P %a %D %T %N')"

# --- 3. meshes ----------------------------------------------------------------------------------------------------
step "meshes in $MESHES"
FAST=(refined_elephant.off bunny00.off fandisk.off knot1.off anchor.off pinion.off cow.off sphere.off)
BIG=refined_elephant.off  # the largest file: baked first in the slow mesh's shard (largest first), and quick
TILED_FROM=elk.off
SOURCE=${VOXFMT_SLURM_MESHES:-${BUILD_DIR:-build}/cgal-data/data/meshes}
ARCHIVE=/usr/share/doc/libcgal-dev/data.tar.gz  # shipped by libcgal-demo; CMake extracts it into the build
if [ ! -f "$SOURCE/$BIG" ]; then
  [ -f "$ARCHIVE" ] || fail "no CGAL sample meshes: neither $SOURCE nor $ARCHIVE (apt-get install libcgal-demo)"
  SOURCE=$WORK/cgal-data/data/meshes
  mkdir -p "$WORK/cgal-data"
  tar -xzf "$ARCHIVE" -C "$WORK/cgal-data" "${FAST[@]/#/data/meshes/}" "data/meshes/$TILED_FROM"
fi
for m in "${FAST[@]}"; do cp "$SOURCE/$m" "$MESHES/"; done
# The tool is on the shared file system too (and a rebuild of the checkout during the test changes nothing).
mkdir -p "$SHARED/bin"
cp "$VOXFMT" "$SHARED/bin/voxfmt"
info "voxfmt: $VOXFMT ($("$VOXFMT" --version 2>/dev/null || echo "no --version")), copied to $SHARED/bin"
VOXFMT=$SHARED/bin/voxfmt
# The slow mesh: copies of the elk turned about its vertical axis, each through all the others (hundreds of thousands
# of self-intersecting face pairs: the repair and the band take seconds on one core, where each CGAL sample takes a
# fraction of one; tiled copies that do not touch became too fast to interrupt once broken meshes baked quickly).
# As many copies as keep it smaller than $BIG (baked first in their shard, largest first). Its name is chosen so
# that it hashes (FNV-1a 64, the README's sharding) into the shard of $BIG, so its task has finished a mesh before
# the fault.
read -r SLOW VICTIM COPIES < <("$PY" - "$SOURCE/$TILED_FROM" "$MESHES" "$BIG" "$SHARDS" <<'EOF'
import math, os, sys
source, folder, big, shards = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])

def shard(name):
    h = 0xcbf29ce484222325
    for byte in name.encode():
        h = ((h ^ byte) * 0x100000001b3) & 0xFFFFFFFFFFFFFFFF
    return h % shards

words = []
for line in open(source):
    words += line.split('#')[0].split()
assert words[0] == 'OFF', source
nv, nf = int(words[1]), int(words[2])
at = 4
vertices = [tuple(float(x) for x in words[at + 3 * i:at + 3 * i + 3]) for i in range(nv)]
at += 3 * nv
faces = []
for _ in range(nf):
    k = int(words[at])
    faces.append([int(x) for x in words[at + 1:at + 1 + k]])
    at += 1 + k
centre = [sum(v[a] for v in vertices) / nv for a in range(3)]

def copy(i, n):  # copy i of n: vertices turned by 2 pi i / n about the vertical axis through the centre
    c, s = math.cos(2 * math.pi * i / n), math.sin(2 * math.pi * i / n)
    lines = []
    for x, y, z in vertices:
        x, z = x - centre[0], z - centre[2]
        lines.append(f'{c * x - s * z:.5g} {y:.5g} {s * x + c * z:.5g}\n')
    return lines

def text(n):
    out = [f'OFF\n{n * nv} {n * nf} 0\n']
    for i in range(n):
        out += copy(i, n)
    for i in range(n):
        out += [f'{len(f)} ' + ' '.join(str(v + i * nv) for v in f) + '\n' for f in faces]
    return ''.join(out)

limit = os.path.getsize(f'{folder}/{big}')
n, kept = 8, text(8)
while len(bigger := text(n + 4)) < limit:
    n, kept = n + 4, bigger
name = next(m for m in (f'elk-turned-{k}.off' for k in range(100)) if shard(m) == shard(big))
with open(f'{folder}/{name}', 'w') as out:
    out.write(kept)
print(name, shard(name), n)
EOF
) || true
[ -n "$SLOW" ] || fail "could not make the slow mesh"
[ "$(stat -c %s "$MESHES/$BIG")" -gt "$(stat -c %s "$MESHES/$SLOW")" ] ||
  fail "$BIG must be larger than $SLOW (baked first in their shard)"
MESH_NAMES=$(cd "$MESHES" && ls)
info "$(wc -l <<<"$MESH_NAMES") meshes: $(tr '\n' ' ' <<<"$MESH_NAMES")"
info "slow mesh: $SLOW ($(stat -c %s "$MESHES/$SLOW") bytes, $COPIES elks through each other), in the shard of $BIG"

# --- 4. the README's job script -----------------------------------------------------------------------------------
step "job script: the README's Slurm job array, sizes and paths replaced"
# Sizes for this machine: one CPU per task (-j 1: tasks run side by side), 2 GB per task, of which 1700 MiB of
# address space per bake (the README's ratio, 7000 MiB of 32 GB / 4), 10 minutes. Paths: this test's folders.
# One line is added after `set -u`: it appends the task and its restart count to starts.log.
"$PY" - README.md "$CHECK/readme-job.sh" "$JOBS/library.sh" "$SHARDS" "$VOXFMT" "$MESHES" "$ASSETS" \
  "$JOBS/starts.log" <<'EOF' ||
import sys
readme, original, target, shards, voxfmt, meshes, assets, starts = sys.argv[1:]
text = open(readme).read()
anchor = 'A Slurm job array over a shared file system:'
if anchor not in text:
    sys.exit(f'{readme}: no "{anchor}" before the job script')
after = text[text.index(anchor):]
begin = after.index('```sh\n') + len('```sh\n')
script = after[begin:after.index('```', begin)]
open(original, 'w').write(script)
counter = ('echo "task=$SLURM_ARRAY_TASK_ID job=$SLURM_JOB_ID restart=${SLURM_RESTART_COUNT:-0}" '
           f'>>"{starts}"  # added by scripts/test-slurm.sh\n')
replacements = [  # (README, this test): each must occur exactly once
    ('#SBATCH --array=0-15 ', f'#SBATCH --array=0-{int(shards) - 1} '),
    ('# 16 shards:', f'# {shards} shards:'),
    ('shards=16 ', f'shards={shards} '),
    ('#SBATCH --cpus-per-task=8\n', '#SBATCH --cpus-per-task=1\n'),
    ('#SBATCH --mem=32G\n', '#SBATCH --mem=2G\n'),
    ('#SBATCH --time=04:00:00\n', '#SBATCH --time=00:10:00\n'),
    ('voxfmt batch /shared/meshes -o /shared/assets', f'"{voxfmt}" batch "{meshes}" -o "{assets}"'),
    (' -j 4 ', ' -j 1 '),
    ('--max-memory 7000\n', '--max-memory 1700\n'),
    ('set -u\n', 'set -u\n' + counter),
]
for old, new in replacements:
    if script.count(old) != 1:
        sys.exit(f'{readme}: the Slurm job script has changed: {old!r} occurs {script.count(old)} times, not once')
    script = script.replace(old, new)
for needed in ('#!/bin/bash\n', '#SBATCH --requeue', '--shard "$SLURM_ARRAY_TASK_ID/$shards"'):
    if needed not in script:
        sys.exit(f'{readme}: the Slurm job script has changed: no {needed!r}')
open(target, 'w').write(script)
EOF
  fail "cannot derive the job script from README.md (see above)"
diff "$CHECK/readme-job.sh" "$JOBS/library.sh" | sed -n 's/^[<>] /   &/p' || true

# --- 5. submit, fault, wait ---------------------------------------------------------------------------------------
step "sbatch (3 shards into $ASSETS)"
submitted=$SECONDS
JOB=$(cd "$JOBS" && env "$MARKER" sbatch --parsable --output="$JOBS/task-%a.log" --open-mode=append library.sh)
JOB=${JOB%%;*}
TASK=${JOB}_$VICTIM
info "job array $JOB; task $TASK bakes $SLOW"
deadline=$((SECONDS + ARRAY_TIMEOUT))

task_field() {  # FIELD: a field of `scontrol show job` for the victim task
  timeout 5 scontrol -o show job "$TASK" 2>/dev/null | tr ' ' '\n' | sed -n "s/^$1=//p" | head -1
}
fail_with_logs() {
  squeue -j "$JOB" -t all >&2 || true
  for f in "$JOBS"/task-*.log; do printf -- '--- %s\n' "$f" >&2; tail -n 20 "$f" >&2; done
  daemon_logs
  fail "$*"
}
slow_bake_pid() {  # the `voxfmt build $SLOW` process of the victim task, if it runs
  local raw pid cmd
  raw=$(task_field JobId)
  [ "$(task_field JobState)" = RUNNING ] && [ -n "$raw" ] || return 0
  for pid in $(timeout 5 scontrol listpids "$raw" 2>/dev/null | awk 'NR > 1 && $1 ~ /^[0-9]+$/ { print $1 }'); do
    cmd=$(tr '\0' ' ' <"/proc/$pid/cmdline" 2>/dev/null) || continue
    if [[ $cmd == *" build "* && $cmd == *" -- $MESHES/$SLOW "* ]]; then  # batch's child: build ... -- MESH
      echo "$pid"
      return
    fi
  done
}
snapshot() {  # N: the victim shard's assets (inode, mtime) and manifest at fault N
  "$PY" -c 'import os, sys
for name in sorted(os.listdir(sys.argv[1])):
    if name.endswith(".vox.h5"):
        st = os.stat(os.path.join(sys.argv[1], name))
        print(name, st.st_ino, st.st_mtime_ns)' "$ASSETS" >"$CHECK/fault-$1.assets"
  cp "$ASSETS/manifest.shard-$VICTIM-of-$SHARDS.jsonl" "$CHECK/fault-$1.manifest.jsonl" 2>/dev/null ||
    : >"$CHECK/fault-$1.manifest.jsonl"
}

n=0
for fault in $FAULTS; do
  n=$((n + 1))
  seen=
  while :; do
    [ "$SECONDS" -lt "$deadline" ] || fail_with_logs "fault $n ($fault): $SLOW never ran for $FAULT_AFTER_MS ms in $TASK"
    pid=$(slow_bake_pid)
    case $(task_field JobState) in
      "" | PENDING | CONFIGURING | RUNNING | COMPLETING) ;;
      *) fail_with_logs "fault $n ($fault): $TASK ended ($(task_field JobState)) before $SLOW ran for $FAULT_AFTER_MS ms" ;;
    esac
    if [ -n "$pid" ]; then
      [ -n "$seen" ] || seen=$(now_ms)
      [ $(($(now_ms) - seen)) -lt "$FAULT_AFTER_MS" ] || break
    else
      seen=
      if [ -f "$ASSETS/$SLOW.vox.h5" ]; then
        fail "fault $n ($fault): $SLOW was baked before the fault (bake too fast to interrupt on this machine?)"
      fi
    fi
    sleep 0.2
  done
  snapshot "$n"
  restarts=$(task_field Restarts)
  case $fault in
    kill)
      raw=$(task_field JobId)
      pids=$(timeout 5 scontrol listpids "$raw" | awk 'NR > 1 && $1 ~ /^[0-9]+$/ { print $1 }' | tr '\n' ' ')
      info "fault $n: $SLOW baking for $(($(now_ms) - seen)) ms in $TASK: SIGKILL to its processes $pids"
      # shellcheck disable=SC2086
      kill -KILL $pids 2>/dev/null || true
      while :; do
        state=$(task_field JobState)
        case $state in RUNNING | COMPLETING) ;; *) break ;; esac
        [ "$SECONDS" -lt "$deadline" ] || fail_with_logs "fault $n: $TASK did not end after SIGKILL"
        sleep 0.2
      done
      info "         $TASK ended $state (exit $(task_field ExitCode)); scontrol requeue $TASK"
      scontrol requeue "$TASK"
      ;;
    requeue)
      info "fault $n: $SLOW baking for $(($(now_ms) - seen)) ms in $TASK: scontrol requeue $TASK (Slurm's SIGTERM)"
      scontrol requeue "$TASK"
      ;;
    *) fail "unknown fault '$fault' in VOXFMT_SLURM_FAULTS (kill, requeue)" ;;
  esac
  while [ "$(task_field Restarts)" = "$restarts" ]; do
    [ "$SECONDS" -lt "$deadline" ] || fail_with_logs "fault $n: $TASK was not requeued"
    sleep 0.2
  done
  info "         $TASK: $(task_field JobState), Restarts=$(task_field Restarts), eligible $(task_field EligibleTime)"
done

step "waiting for the array to finish (at most $((deadline - SECONDS)) s more)"
while :; do
  active=$(timeout 10 squeue -h -j "$JOB" -o '%i %T' 2>&1) || fail_with_logs "squeue failed: $active"
  [ -n "$active" ] || break
  [ "$SECONDS" -lt "$deadline" ] || fail_with_logs "the job array did not finish within $ARRAY_TIMEOUT s"
  sleep 0.5
done
array_seconds=$((SECONDS - submitted))
scontrol -o show job "$JOB" >"$CHECK/jobs.txt"
info "finished after $array_seconds s:"
while read -r line; do
  info "$(tr ' ' '\n' <<<"$line" | grep -E '^(ArrayTaskId|JobState|ExitCode|Restarts|RunTime)=' | tr '\n' ' ')"
done <"$CHECK/jobs.txt"
info "task $TASK's log (each run appends; the per-mesh lines left out):"
grep -E '^voxfmt batch: ' "$JOBS/task-$VICTIM.log" | sed 's/^/     /' || true

# --- 6. checks ----------------------------------------------------------------------------------------------------
step "checks"
FAULT_COUNT=$n
invalid=0
for name in $MESH_NAMES; do
  [ -f "$ASSETS/$name.vox.h5" ] || continue
  if ! "$VOXFMT" validate --level full "$ASSETS/$name.vox.h5" >"$CHECK/validate.txt" 2>&1; then
    sed 's/^/     /' "$CHECK/validate.txt"
    invalid=$((invalid + 1))
  fi
done
# One line per check on stderr (ok: / FAILED:), the counts "PASSED FAILED" on stdout.
counts=$("$PY" - "$MESHES" "$ASSETS" "$JOBS" "$CHECK" "$SHARDS" "$VICTIM" "$FAULT_COUNT" "$BIG" "$SLOW" "$JOB" \
  "$SLURM_DIR/log/jobcomp.log" "$FAULTS" "$invalid" <<'EOF'
import glob, json, os, re, sys
meshdir, assets, jobs, check = sys.argv[1:5]
shards, victim, faults = (int(a) for a in sys.argv[5:8])
big, slow, job, jobcomp, kinds, invalid = sys.argv[8:14]
meshes = sorted(os.listdir(meshdir))
results = []

def report(what, problems):
    results.append(not problems)
    print(f'   {"ok" if not problems else "FAILED"}: {what}', file=sys.stderr)
    for p in problems:
        print(f'       {p}', file=sys.stderr)

def shard(name):
    h = 0xcbf29ce484222325
    for byte in name.encode():
        h = ((h ^ byte) * 0x100000001b3) & 0xFFFFFFFFFFFFFFFF
    return h % shards

def fields(line):
    return dict(kv.split('=', 1) for kv in line.split() if '=' in kv)

def name_of(output):
    return os.path.relpath(output, assets)[:-len('.vox.h5')]

report('every asset passes voxfmt validate --level full', [f'{invalid} invalid'] if invalid != '0' else [])

found = sorted(os.path.relpath(p, assets) for p in glob.glob(assets + '/**/*', recursive=True) if os.path.isfile(p))
got = [f for f in found if f.endswith('.vox.h5')]
expected = sorted(m + '.vox.h5' for m in meshes)
report('one asset per mesh', [] if got == expected else [f'assets {got}, expected {expected}'])
partials = [f for f in found if '.partial-' in f]
others = [f for f in found if f not in got and f not in partials
          and not re.fullmatch(r'manifest\.shard-\d+-of-\d+\.jsonl(\.lock)?', f)]
report('no *.partial-* temporary, nothing else in the output folder',
       [f'temporaries: {partials}'] * bool(partials) + [f'other files: {others}'] * bool(others))

# The last record of an output is its state: every mesh in exactly one shard's manifest, in the shard its name
# hashes to (FNV-1a 64), ok or up_to_date; no failed record at all (a bake stopped by Slurm is not the mesh's fault).
want = [f'{assets}/manifest.shard-{i}-of-{shards}.jsonl' for i in range(shards)]
problems = [] if sorted(glob.glob(assets + '/manifest*.jsonl')) == want else [f'manifests: expected {want}']
failed_records = []
final, where = {}, {}
for i, path in enumerate(want):
    last = {}
    for line in open(path) if os.path.exists(path) else []:
        record = json.loads(line)
        last[record['output']] = record
        if record['status'] == 'failed':
            failed_records.append(f'{os.path.basename(path)}: {record["input"]}: {record.get("error")}')
    for output, record in last.items():
        name = name_of(output)
        if name in final: problems.append(f'{name} in the manifests of shards {where[name]} and {i}')
        final[name], where[name] = record, i
        if record['status'] not in ('ok', 'up_to_date'): problems.append(f'{name}: final status {record["status"]}')
        if shard(name) != i: problems.append(f'{name} in shard {i}; its name hashes to shard {shard(name)}')
if sorted(final) != meshes: problems.append(f'manifests list {sorted(final)}, not {meshes}')
states = ', '.join(f'{s} {sum(r["status"] == s for r in final.values())}' for s in ('ok', 'up_to_date'))
report(f'the manifests list every mesh once, in its hash shard ({states})', problems)
report('no failed record in the manifests', failed_records)

# The task logs (appended across restarts) have one "ok" line per bake.
baked = {m: 0 for m in meshes}
for path in glob.glob(jobs + '/task-*.log'):
    for line in open(path):
        hit = re.match(r'\[\d+/\d+\] ok +' + re.escape(meshdir) + r'/(\S+) \(', line)
        if hit: baked[hit.group(1)] = baked.get(hit.group(1), 0) + 1
report('every mesh baked successfully exactly once (task logs)',
       [f'{m}: {c} times' for m, c in baked.items() if c != 1])

# What was finished before a fault stays: same file (inode, mtime), no new ok record.
problems = []
done_before = []
for n in range(1, faults + 1):
    before = dict((l.split()[0], tuple(l.split()[1:])) for l in open(f'{check}/fault-{n}.assets'))
    records = {name_of(r['output']): r for r in map(json.loads, open(f'{check}/fault-{n}.manifest.jsonl'))}
    done = [m for m in meshes if shard(m) == victim and m + '.vox.h5' in before]
    done_before.append(f'fault {n}: {", ".join(done) or "none"}')
    if n == 1 and big not in done: problems.append(f'fault 1: {big} was not finished before it')
    if slow in done: problems.append(f'fault {n}: {slow} was finished before it')
    for m in done:
        st = os.stat(f'{assets}/{m}.vox.h5')
        if (str(st.st_ino), str(st.st_mtime_ns)) != before[m + '.vox.h5']:
            problems.append(f'fault {n}: {m}.vox.h5 was rewritten after it')
        if final.get(m, {}).get('status') == 'ok' and final[m].get('finished_utc') != records.get(m, {}).get('finished_utc'):
            problems.append(f'fault {n}: {m} has a new ok record after it')
report(f'assets finished before a fault were not baked again ({"; ".join(done_before)})', problems)

# Slurm's SIGTERM: voxfmt stops, records nothing, says "interrupted" (a SIGKILLed run prints no summary).
log = open(f'{jobs}/task-{victim}.log').read()
interrupted = len(re.findall(r'^voxfmt batch: .* not finished \(interrupted\) in ', log, re.M))
want_interrupted = kinds.split().count('requeue')
report(f'task {victim}: {interrupted} "interrupted" summaries (one per SIGTERM)',
       [] if interrupted == want_interrupted else [f'expected {want_interrupted}'])

# Restarts: the job script of the victim ran 1 + faults times (starts.log, SLURM_RESTART_COUNT), the others once;
# every task ended COMPLETED with exit 0 (scontrol); Slurm's job completion log saw the runs.
starts = [fields(line) for line in open(jobs + '/starts.log')]
runs = {i: sorted(int(s['restart']) for s in starts if int(s['task']) == i) for i in range(shards)}
problems = []
for i in range(shards):
    want_runs = list(range(faults + 1)) if i == victim else [0]
    if runs[i] != want_runs: problems.append(f'task {i} ran with restart counts {runs[i]}, expected {want_runs}')
report(f'task {victim} ran {len(runs[victim])} times (SLURM_RESTART_COUNT {runs[victim]}), the others once', problems)
problems = []
for line in open(check + '/jobs.txt'):
    f = fields(line)
    want_restarts = str(faults if f['ArrayTaskId'] == str(victim) else 0)
    if (f['JobState'], f['ExitCode'], f['Restarts']) != ('COMPLETED', '0:0', want_restarts):
        problems.append(f'task {f["ArrayTaskId"]}: {f["JobState"]} exit {f["ExitCode"]} Restarts={f["Restarts"]}, '
                        f'expected COMPLETED exit 0:0 Restarts={want_restarts}')
report(f'scontrol: every task COMPLETED with exit 0, task {victim} with Restarts={faults}', problems)
ends = [f for f in map(fields, open(jobcomp)) if f.get('ArrayJobId') == job and f.get('ArrayTaskId') == str(victim)]
started = sorted({f['StartTime'] for f in ends})
report(f'jobcomp, task {victim}: ' + ', '.join(f'{f["JobState"]} (started {f["StartTime"][11:]})' for f in ends),
       [] if len(started) == faults + 1 and ends[-1]['JobState'] == 'COMPLETED'
       else [f'expected {faults + 1} runs, the last COMPLETED'])
print(sum(results), len(results) - sum(results))
EOF
)
read -r passed failed <<<"$counts"
if [ "${failed:-1}" != 0 ]; then
  for f in "$JOBS"/task-*.log; do printf -- '--- %s\n' "$f"; cat "$f"; done
  RESULT="test-slurm: ${passed:-0} passed, ${failed:-1} failed"
  fail "${failed:-?} check(s) failed (task logs above; everything is in $WORK)"
fi

# --- 7. summary ---------------------------------------------------------------------------------------------------
step "summary"
info "$(wc -l <<<"$MESH_NAMES") meshes, $SHARDS shards (job array $JOB), one output folder: $ASSETS"
info "task $TASK (slow mesh $SLOW) interrupted $FAULT_COUNT time(s) mid-bake ($FAULTS), ran $((FAULT_COUNT + 1)) times"
info "array: $array_seconds s from sbatch to the last task; whole test: $((SECONDS - START_SECONDS)) s"
RESULT="test-slurm: $passed passed, 0 failed"
