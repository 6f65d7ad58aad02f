# pipeline.sh --farm slurm against a one-node Slurm brought up here (munged, slurmctld and slurmd in the
# foreground on loopback, generated slurm.conf, stopped by pid at the end): the job graph runs, a bake told
# to leave before its time limit checkpoints, requeues itself and resumes, resubmitting is idempotent, and
# every frame cache, mesh and image equals a local pipeline.sh run's byte for byte.
#
# Where Slurm is not installed and cannot be (not root), the test says SKIP with the reason. As root with
# the packages present (CI: make test installs them), a Slurm that does not come up is a failure.
source "$(dirname "$0")/lib.sh"
scene="$ROOT/tests/data/farm_dam.json"
shot=farm_dam

tools=(munged slurmctld slurmd sbatch squeue scontrol scancel sinfo)
missing=()
for t in "${tools[@]}"; do command -v "$t" >/dev/null || missing+=("$t"); done
if [ ${#missing[@]} -gt 0 ]; then
  echo "SKIP farm: ${missing[*]} not installed (Debian packages slurmctld slurmd slurm-client munge; make test installs them when run as root)"
  exit 0
fi
cannot_start() {
  if [ "$(id -u)" = 0 ]; then fail "slurm starts" "$1"; else echo "SKIP farm: Slurm could not start here: $1"; fi
  exit 0
}

# ---- a one-node cluster -------------------------------------------------------------------------------
S="$WORK/slurm"
mkdir -p "$S/munge" "$S/state" "$S/spool" "$S/log"
chmod 700 "$S/munge"
head -c 1024 /dev/urandom > "$S/munge/munge.key"
chmod 400 "$S/munge/munge.key"
pids=()
stop_cluster() {
  local p
  for p in "$S/slurmd.pid" "$S/slurmctld.pid" "$S/munge/munged.pid"; do
    [ -f "$p" ] && kill "$(cat "$p")" 2>/dev/null
  done
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null; done
  sleep 1
  # on a failure, what Slurm and the jobs said goes into the test log before the folder goes
  if [ -n "${farm_failed:-}" ]; then
    echo "---- slurmctld.log (tail)"; tail -40 "$S/log/slurmctld.log" 2>/dev/null
    echo "---- slurmd.log (tail)"; tail -20 "$S/log/slurmd.log" 2>/dev/null
    for f in "${farm_out:-/nonexistent}"/*/farm/logs/*; do [ -f "$f" ] && { echo "---- $f"; tail -15 "$f"; }; done
  fi
  rm -rf "$WORK"
}
trap stop_cluster EXIT
fail() { farm_failed=1; echo "FAIL $1: $2"; }

node=$(hostname -s)
port=$((20000 + RANDOM % 20000))
cat > "$S/slurm.conf" <<EOF
ClusterName=drenchtest
SlurmctldHost=$node(127.0.0.1)
SlurmctldPort=$port
SlurmdPort=$((port + 1))
AuthType=auth/munge
AuthInfo=socket=$S/munge/munge.socket
CredType=cred/munge
SlurmUser=$(id -un)
SlurmdUser=root
StateSaveLocation=$S/state
SlurmdSpoolDir=$S/spool
SlurmctldPidFile=$S/slurmctld.pid
SlurmdPidFile=$S/slurmd.pid
SlurmctldLogFile=$S/log/slurmctld.log
SlurmdLogFile=$S/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SwitchType=switch/none
MpiDefault=none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
MinJobAge=600
NodeName=$node NodeAddr=127.0.0.1 CPUs=$(nproc) State=UNKNOWN
PartitionName=drench Nodes=$node Default=YES MaxTime=INFINITE State=UP
EOF
export SLURM_CONF="$S/slurm.conf"
munged -F -f --socket="$S/munge/munge.socket" --key-file="$S/munge/munge.key" --log-file="$S/log/munged.log" \
  --pid-file="$S/munge/munged.pid" --seed-file="$S/munge/seed" >"$S/log/munged.out" 2>&1 &
pids+=($!)
for _ in $(seq 50); do [ -S "$S/munge/munge.socket" ] && break; sleep 0.1; done
[ -S "$S/munge/munge.socket" ] || cannot_start "munged did not start: $(tail -2 "$S/log/munged.out")"
slurmctld -D -i >"$S/log/slurmctld.out" 2>&1 &
pids+=($!)
sleep 1
slurmd -D >"$S/log/slurmd.out" 2>&1 &
pids+=($!)
state=""
for _ in $(seq 60); do
  state=$(sinfo -h -o %t 2>/dev/null | head -1)
  [ "$state" = idle ] && break
  sleep 0.5
done
[ "$state" = idle ] || cannot_start "node state '$state' after 30 s: $(tail -3 "$S/log/slurmctld.log" "$S/log/slurmd.log" 2>/dev/null | tr '\n' ' ')"
pass "one-node Slurm is up (munged, slurmctld, slurmd on 127.0.0.1:$port)"

# ---- the local reference ------------------------------------------------------------------------------
local_out="$WORK/local" farm_out="$WORK/farm"
DRENCH_OUT="$local_out" "$ROOT/pipeline.sh" --no-build "$scene" >"$WORK/local.log" 2>&1
check "local pipeline run succeeds" test -f "$local_out/$shot/render/MANIFEST"

# ---- dry run: scripts printed, nothing submitted or written --------------------------------------------
out=$(DRENCH_OUT="$farm_out" DRENCH_SLURM_CHUNK=4 "$ROOT/pipeline.sh" --no-build --farm slurm --dry-run "$scene" 2>&1)
check "dry run prints the bake's signal and requeue lines" \
  test "$(grep -c -e '^#SBATCH --signal=B:USR1@' -e '^#SBATCH --requeue$' -e '^#SBATCH --open-mode=append$' <<<"$out")" -eq 3
# sbatch ignores #SBATCH lines after the first command: every script's directives must come first.
late=$(awk '/^----- sbatch/ {cmd = 0; next} /^#SBATCH/ && cmd {print; next} !/^#/ && NF {cmd = 1}' <<<"$out")
check "dry run: every #SBATCH line precedes the script's commands" test -z "$late"
check "dry run prints mesh and render arrays of 3 chunks" test "$(grep -c 'SBATCH --array=0-2' <<<"$out")" -eq 2
check "dry run chains jobs with afterok" test "$(grep -c 'dependency=afterok' <<<"$out")" -ge 5
check "dry run submits nothing" test -z "$(squeue -h)"
check "dry run writes no scripts" test ! -e "$farm_out/$shot/farm"

# ---- the farm run ---------------------------------------------------------------------------------------
# Jobs submitted to a DOWN partition stay pending, so resubmission is checked against a known queue.
scontrol update PartitionName=drench State=DOWN
submit() { DRENCH_OUT="$farm_out" DRENCH_SLURM_CHUNK=4 DRENCH_SLURM_CPUS=2 "$ROOT/pipeline.sh" --no-build --farm slurm "$scene" 2>&1; }
out=$(submit); rc=$?
echo "$out"
check "farm submission succeeds" test "$rc" -eq 0
check "4 stages submitted" bash -c "grep -q 'pipeline: 4 stage(s) submitted' <<<'$out'"
check "sbatch scripts kept in the shot folder" test "$(ls "$farm_out/$shot/farm/"*.sbatch 2>/dev/null | wc -l)" -eq 6
check "job graph written" test -s "$farm_out/$shot/farm/jobs.txt"
jobs_before=$(squeue -h -r | wc -l)
out=$(submit)
check "resubmitting while queued reuses every queued job" \
  test "$(grep -c 'already queued' <<<"$out")" -eq 6 -a "$(squeue -h -r | wc -l)" -eq "$jobs_before"
scontrol update PartitionName=drench State=UP

# Near its time limit Slurm sends the bake's batch shell SIGUSR1 (--signal=B:USR1@...). Send it now, while
# frames are being baked: the bake checkpoints, the job requeues itself and resumes from the checkpoint.
bake_job=$(squeue -h -n "$(ls "$farm_out/$shot/farm/" | sed -n 's/^\(drench-farm_dam-bake-[0-9a-f]*\)\.sbatch$/\1/p')" -o %i | head -1)
progress="$farm_out/$shot/bake/progress.jsonl"
for _ in $(seq 600); do
  [ -f "$progress" ] && [ "$(wc -l <"$progress")" -ge 2 ] && break
  sleep 0.1
done
if [ -n "$bake_job" ] && scancel --signal=USR1 --batch "$bake_job" 2>/dev/null; then
  requeued=0
  for _ in $(seq 300); do
    scontrol show job "$bake_job" 2>/dev/null | grep -q 'Restarts=1' && { requeued=1; break; }
    sleep 0.1
  done
  check "bake job requeued itself after the warning signal" test "$requeued" -eq 1
  # Slurm holds a requeued job for about two minutes before it may start again; release it sooner, but only
  # once it is pending again and a few seconds after the old run's end: slurmd refuses to launch a job
  # whose new credential dates from the same second as the revocation of the old one ("Job credential
  # revoked"), which fails the job and cancels its dependents.
  for _ in $(seq 300); do
    scontrol show job "$bake_job" 2>/dev/null | grep -q 'JobState=PENDING' && break
    sleep 0.1
  done
  sleep 3
  scontrol update JobId="$bake_job" StartTime=now >/dev/null 2>&1
else
  fail "bake job requeued itself after the warning signal" "no running bake job to signal (job '$bake_job')"
fi

for _ in $(seq 900); do [ -z "$(squeue -h)" ] && break; sleep 1; done
check "every job finished within 15 minutes" test -z "$(squeue -h)"
logs="$farm_out/$shot/farm/logs"
bake_log=$(cat "$logs"/drench-farm_dam-bake-* 2>/dev/null)
if grep -q 'requeueing job' <<<"$bake_log" && grep -q 'resuming after frame' <<<"$bake_log"; then
  pass "bake checkpointed at the signal and the requeued job resumed"
else
  fail "bake checkpointed at the signal and the requeued job resumed" \
    "the bake job's log lacks 'requeueing job' or 'resuming after frame'; it ends: $(tail -8 <<<"$bake_log" | tr '\n' '|')"
fi
for st in precompute bake mesh render; do
  want=$(awk '$1=="key"{print $2}' "$local_out/$shot/$st/MANIFEST" 2>/dev/null)
  got=$(awk '$1=="key"{print $2}' "$farm_out/$shot/$st/MANIFEST" 2>/dev/null)
  check "farm $st MANIFEST has the local run's key" test -n "$got" -a "$got" = "$want"
done
same() { # DIR GLOB: every local file matching has a byte-identical farm twin
  local f n=0 bad=0
  for f in "$local_out/$shot/$1"/$2; do
    n=$((n + 1))
    cmp -s "$f" "$farm_out/$shot/$1/$(basename "$f")" || { echo "differs: $f"; bad=1; }
  done
  [ "$n" -gt 0 ] && [ "$bad" = 0 ]
}
check "frame caches identical to the local run" same bake 'frame.*.h5'
check "liquid OBJs identical" same mesh '*.obj'
check "liquid VDBs identical" same mesh '*.vdb'
check "frame PNGs identical" same render 'frame.*.png'
check "contact sheet identical" same render contact_sheet.png
check "plots written by the render --finish job" test "$(ls "$farm_out/$shot/render/plots/"*.png 2>/dev/null | wc -l)" -ge 3
out=$(submit)
check "everything up to date: nothing submitted" bash -c "grep -q 'pipeline: 0 stage(s) submitted' <<<'$out'"
check "no failed job logs" bash -c "! grep -l 'error' '$logs'/*render* '$logs'/*mesh* 2>/dev/null | grep -q ."

# ---- the default shot on the farm -------------------------------------------------------------------------------
# The default shot (a wet fur dunked into a tank beside the jelly: capture, dripping, the coupled loop, a BEM body),
# made small as in test_default_shot.sh, 12 frames: the farm's frames, meshes and images equal a local run's.
mkdir -p "$WORK/dscenes" "$WORK/meshes"
cp "$ROOT"/assets/meshes/*.obj "$WORK/meshes/"
dscene="$WORK/dscenes/default_small.json"
python3 "$ROOT/tests/pipeline/small_default.py" "$ROOT/assets/scenes/default.json" "$dscene" 12
shot=default_small
DRENCH_OUT="$local_out" "$ROOT/pipeline.sh" --no-build "$dscene" -j 2 >"$WORK/dlocal.log" 2>&1
check "default shot: local pipeline run succeeds" test -f "$local_out/$shot/render/MANIFEST"
out=$(DRENCH_OUT="$farm_out" DRENCH_SLURM_CHUNK=4 DRENCH_SLURM_CPUS=2 "$ROOT/pipeline.sh" --no-build --farm slurm "$dscene" 2>&1)
check "default shot: 4 stages submitted" bash -c "grep -q 'pipeline: 4 stage(s) submitted' <<<\"\$1\"" _ "$out"
for _ in $(seq 600); do [ -z "$(squeue -h)" ] && break; sleep 1; done
check "default shot: every job finished within 10 minutes" test -z "$(squeue -h)"
check "default shot: frame caches identical to the local run" same bake 'frame.*.h5'
check "default shot: liquid OBJs identical" same mesh '*.obj'
check "default shot: liquid VDBs identical" same mesh '*.vdb'
check "default shot: frame PNGs identical" same render 'frame.*.png'
