#!/usr/bin/env bash
# drench pipeline: precompute → bake → mesh → render for one scene, rerunning only what changed.
#
#   ./pipeline.sh [SCENE] [--force STAGE] [--from STAGE] [--frames A-B] [-j N] [--no-build] [--no-plots]
#   ./pipeline.sh [SCENE] --farm slurm [--dry-run] [--partition P] [--chunk N] [--time HH:MM:SS]
#   ./pipeline.sh --preview [SCENE] [-j N] [--no-build]    ./pipeline.sh --version
#
# Each stage prints its cache key (`--print-key`); the key is compared with the MANIFEST in the stage's
# output folder, and a stage runs when the two differ, when it is forced, or when an earlier stage ran; bake,
# mesh and render run only for the frames they lack or hold damaged, and a stopped bake is resumed.
# SCENE defaults to assets/scenes/default.json. Outputs go to out/<shot>/ (DRENCH_OUT to change).
# --farm slurm submits the stale stages as Slurm jobs instead (scripts kept in out/<shot>/farm/);
# README "Running on a Slurm farm" lists the DRENCH_SLURM_* settings.
# --preview renders the scene's initial state to out/<shot>/preview.png in seconds, before anything is baked
# (render --preview); no stage runs and no stage folder changes. --frames and -j are checked (exit 2) before
# anything runs, also when every stage is up to date.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
stages=(precompute bake mesh render)
scene=""; force=""; from=""; frames=""; threads=""; build=1; plots=1; preview=0
farm=""; dry_run=0
partition="${DRENCH_SLURM_PARTITION:-}"
chunk="${DRENCH_SLURM_CHUNK:-8}"
time_limit="${DRENCH_SLURM_TIME:-04:00:00}"
bake_time_limit="${DRENCH_SLURM_BAKE_TIME:-24:00:00}"
cpus="${DRENCH_SLURM_CPUS:-}"
signal_lead="${DRENCH_SLURM_SIGNAL_LEAD:-300}"
account="${DRENCH_SLURM_ACCOUNT:-}"
sbatch_extra="${DRENCH_SLURM_SBATCH_ARGS:-}"

die() { echo "pipeline.sh: error: $*" >&2; exit 2; }
usage() { sed -n '2,15p' "$0" | sed 's/^# \{0,1\}//'; }
version() { sed -n 's/^#define DR_VERSION "\(.*\)"$/\1/p' "$here/src/core/core.h"; }
stage_index() { local i; for i in "${!stages[@]}"; do [ "${stages[$i]}" = "$1" ] && { echo "$i"; return; }; done
                die "unknown stage '$1' (stages: ${stages[*]})"; }

while [ $# -gt 0 ]; do
  case "$1" in
    -h|--help) usage; exit 0 ;;
    --version) echo "pipeline.sh (drench) $(version)"; exit 0 ;;
    --preview) preview=1; shift ;;
    --force) [ $# -ge 2 ] || die "--force needs a stage"; force="$2"; stage_index "$2" >/dev/null; shift 2 ;;
    --from) [ $# -ge 2 ] || die "--from needs a stage"; from="$2"; stage_index "$2" >/dev/null; shift 2 ;;
    --frames) [ $# -ge 2 ] || die "--frames needs a range A-B"; frames="$2"; shift 2 ;;
    -j) [ $# -ge 2 ] || die "-j needs a thread count"; threads="$2"; shift 2 ;;
    --resume) shift ;; # the default: a bake whose checkpoint is usable always continues from it
    --no-build) build=0; shift ;;
    --no-plots) plots=0; shift ;;
    --farm) [ $# -ge 2 ] || die "--farm needs a scheduler (slurm)"; farm="$2"; shift 2
            [ "$farm" = slurm ] || die "--farm '$farm' is not supported; use --farm slurm" ;;
    --dry-run) dry_run=1; shift ;;
    --partition) [ $# -ge 2 ] || die "--partition needs a name"; partition="$2"; shift 2 ;;
    --chunk) [ $# -ge 2 ] || die "--chunk needs a frame count"; chunk="$2"; shift 2 ;;
    --time) [ $# -ge 2 ] || die "--time needs a limit like 04:00:00"; time_limit="$2"; shift 2 ;;
    -*) die "unknown option '$1' (see --help)" ;;
    *) [ -z "$scene" ] || die "more than one scene given"; scene="$1"; shift ;;
  esac
done
scene="${scene:-$here/assets/scenes/default.json}"
[ -f "$scene" ] || die "scene '$scene' not found"
# Checked before anything runs, so a typo fails the same whether or not a stage is stale.
[ -z "$threads" ] || { [[ "$threads" =~ ^[1-9][0-9]{0,3}$ ]] && [ "$threads" -le 1024 ]; } \
  || die "-j '$threads' must be a thread count between 1 and 1024"
[ -z "$frames" ] || [[ "$frames" =~ ^[0-9]+-[0-9]+$ ]] || die "--frames '$frames' is not a range like 1-48"
if [ "$preview" = 1 ]; then
  [ -z "$farm$frames$force$from" ] || die "--preview renders the scene's initial state alone; it takes none of --farm, --frames, --force, --from"
fi
if [ -z "$farm" ]; then
  [ "$dry_run" = 0 ] || die "--dry-run needs --farm slurm"
else
  [[ "$chunk" =~ ^[1-9][0-9]*$ ]] || die "--chunk (DRENCH_SLURM_CHUNK) '$chunk' must be a positive frame count"
  [[ "$signal_lead" =~ ^[0-9]+$ ]] || die "DRENCH_SLURM_SIGNAL_LEAD '$signal_lead' must be seconds"
  [ -z "$cpus" ] || [[ "$cpus" =~ ^[1-9][0-9]*$ ]] || die "DRENCH_SLURM_CPUS '$cpus' must be a positive count"
  [ -z "$frames" ] || die "--frames and --farm do not mix: the farm runs whole stages"
fi

t0=$EPOCHREALTIME
if [ "$build" = 1 ]; then
  # Builds only what is missing or out of date; installs missing Debian packages first.
  make -s -C "$here" deps
  make -s -C "$here" -j"$(nproc)" all >/dev/null
fi
bin="$here/bin"
if [ "$preview" = 1 ]; then
  exec "$bin/render" "$scene" --preview ${threads:+-j "$threads"}
fi
# the shot's range (exit 2 naming the shot's frames when --frames leaves it)
[ -z "$frames" ] || "$bin/bake" "$scene" --print-frames --frames "$frames" >/dev/null || exit $?

# Stale stages, in order: a stage runs when forced, when its key differs from its MANIFEST, or when an
# earlier stage runs as a whole. bake, mesh and render work frame by frame: their MANIFEST records the frames
# they hold ("frames A-B"), and with an unchanged key they run only for the frames they lack or that the stage
# before them rewrites. `bake --verify` checks every frame the bake holds (frame number, key, checksums) and the
# checkpoint: a bake runs from its first missing or damaged frame on, continuing with --resume when the
# checkpoint is good and no frame before it is bad, else baking again from the first frame (bit-identically, so
# later stages keep what they made from the good frames).
whole_from=99
[ -n "$from" ] && whole_from=$(stage_index "$from")
declare -A reason_of todo_first todo_last
manifest_field() { # manifest_field DIR FIELD: the value on FIELD's line of DIR/MANIFEST ("key", "frames")
  [ -f "$1/MANIFEST" ] && awk -v f="$2" '$1==f{print $2; exit}' "$1/MANIFEST" || true; }
for i in "${!stages[@]}"; do
  st=${stages[$i]}
  out=$("$bin/$st" --print-key --print-out-dir "$scene") || exit $?
  key=${out%%$'\n'*}; dir=${out#*$'\n'}
  have=$(manifest_field "$dir" key)
  reason=""
  if [ "$i" -ge "$whole_from" ]; then reason="an earlier stage is stale or --from"
  elif [ "$st" = "$force" ]; then reason="--force"
  elif [ -z "$have" ]; then reason="no complete output yet"
  elif [ "$have" != "$key" ]; then reason="inputs changed"
  elif [ "$st" = precompute ]; then
    # the products live in the shared cache, not beside the MANIFEST: a cleared or moved cache is stale too
    while read -r _ kind _ k; do
      [ -f "${DRENCH_CACHE:-cache}/$kind/$k.h5" ] || { reason="its cache entry $kind/$k.h5 is missing"; break; }
    done < <(awk '$1=="input" && NF==4 && length($4)==32' "$dir/MANIFEST")
  fi
  reason_of[$st]="$reason"
  # a frame stage without a MANIFEST may hold frames all the same (a stopped bake): the frames below decide
  partial=0; [ "$st" != precompute ] && [ "$reason" = "no complete output yet" ] && partial=1
  [ -n "$reason" ] && [ "$i" -lt "$whole_from" ] && [ "$partial" = 0 ] && whole_from=$i
  eval "key_$st=\$key; dir_$st=\$dir"
done

# The frames: the shot's (shot_first..shot_last), those asked for (want_first..want_last), the bake's good ones
# (shot_first..good) and its checkpoint. verify [--quick]: asks bake --verify (--quick: the frames' files, numbers
# and keys, not their data).
verify() {
  local verify_args=("$scene" --verify "$@") verify_log="${TMPDIR:-/tmp}/drench-verify.$$" verify_out
  [ -n "$frames" ] && verify_args+=(--frames "$frames")
  verify_rc=0; verify_out=$("$bin/bake" "${verify_args[@]}" 2>"$verify_log") || verify_rc=$?
  verify_msg=$(grep -v '^bake: frames .* are good' "$verify_log" || true); rm -f "$verify_log"
  read -r _ shot_first shot_last < <(echo "$verify_out" | awk '$1=="shot"') || true
  [ -n "${shot_first:-}" ] || { echo "$verify_msg" >&2; exit "$verify_rc"; }
  good=$(echo "$verify_out" | awk '$1=="good_through"{print $2}')
  ckpt=$(echo "$verify_out" | awk '$1=="checkpoint"{print $2}')
  want_first=$shot_first; want_last=$shot_last
  [ -n "$frames" ] && { want_first=${frames%-*}; want_last=${frames#*-}; }
  return 0
}

# frame_stages: the reason and the frames to do of bake, mesh and render from what verify found.
frame_stages() {
  local i st key_var dir_var lo held d1 d2
  redo=$((want_last + 1)) # the first frame the stage before rewrites in this run
  resume=0; damaged_msg=""
  for i in 1 2 3; do
    st=${stages[$i]}
    key_var="key_$st"; dir_var="dir_$st"
    lo=$want_first; [ "$st" = bake ] && lo=$shot_first # a bake starts at the shot's first frame
    if [ "$i" -ge "$whole_from" ]; then
      todo_first[$st]=$lo; todo_last[$st]=$want_last; redo=$want_first; continue
    fi
    # what the MANIFEST holds (under the current key: an older key made the stage stale as a whole above)
    held=$(manifest_field "${!dir_var}" frames)
    d1=""; d2=""
    if [ -n "$(manifest_field "${!dir_var}" key)" ]; then
      if [ -n "$held" ]; then d1=${held%-*}; d2=${held#*-}; else d1=$shot_first; d2=$shot_last; fi
    fi
    if [ "$st" = bake ]; then
      if [ -n "$d2" ] && [ "$d2" -ge "$want_last" ] && [ "$good" -ge "$want_last" ]; then
        reason_of[$st]=""
      else
        todo_first[$st]=$shot_first; todo_last[$st]=$want_last
        if [ -n "$d2" ] && [ "$d2" -gt "$good" ]; then
          reason_of[$st]="frame $((good + 1)) is missing or damaged"
          damaged_msg=$verify_msg # what is wrong with a frame the MANIFEST claims
        elif [ "$good" -lt "$want_last" ]; then
          reason_of[$st]="frames $((good + 1))-$want_last are not baked yet"
        else
          reason_of[$st]="frames $shot_first-$want_last are there but the bake did not finish"
        fi
        if [ "$ckpt" != none ] && [ "$ckpt" -le "$good" ]; then
          resume=1; reason_of[$st]+="; continuing after frame $ckpt (--resume)"
        elif [ "$good" -ge "$shot_first" ]; then
          reason_of[$st]+="; baking again from frame $shot_first (no usable checkpoint before frame $((good + 1)))"
        fi
        redo=$((good + 1))
      fi
      continue
    fi
    [ -n "$d2" ] && [ "$d2" -ge "$redo" ] && d2=$((redo - 1))
    if [ -n "$d1" ] && [ "$d1" -le "$want_first" ] && [ "$d2" -ge "$want_last" ]; then
      reason_of[$st]=""; redo=$((want_last + 1))
    elif [ -n "$d1" ] && [ "$d1" -le "$want_first" ] && [ "$d2" -ge "$want_first" ]; then
      todo_first[$st]=$((d2 + 1)); todo_last[$st]=$want_last; redo=$((d2 + 1))
      reason_of[$st]="frames $((d2 + 1))-$want_last to do (frames $d1-$d2 kept)"
    else
      todo_first[$st]=$want_first; todo_last[$st]=$want_last; redo=$want_first
      reason_of[$st]="frames $want_first-$want_last to do"
    fi
  done
}

good=""; ckpt=none
if [ "$whole_from" -le 1 ]; then
  read -r shot_first shot_last < <("$bin/bake" --print-frames "$scene") || exit $?
  want_first=$shot_first; want_last=$shot_last
  [ -n "$frames" ] && { want_first=${frames%-*}; want_last=${frames#*-}; }
  frame_stages
else
  # The frames' data are read only when a stage is going to run: a run with nothing to do checks that every frame
  # is there, holds its own number and was baked under the current key (a few milliseconds a frame); bake --verify
  # and every stage that reads the frames check their data whole.
  verify --quick
  frame_stages
  if [ -n "${reason_of[bake]}${reason_of[mesh]}${reason_of[render]}" ]; then
    verify
    frame_stages
  fi
  [ -z "$damaged_msg" ] || echo "$damaged_msg" >&2
fi

if [ -z "$farm" ]; then
  extra=()
  [ -n "$threads" ] && extra+=(-j "$threads")
  ran=0; skipped=0
  for st in "${stages[@]}"; do
    key_var="key_$st"
    if [ -z "${reason_of[$st]}" ]; then
      echo "$st: up to date (key ${!key_var})"; skipped=$((skipped + 1)); continue
    fi
    echo "$st: running (${reason_of[$st]})"
    args=("$scene" "${extra[@]}")
    if [ "$st" != precompute ]; then
      a=${todo_first[$st]}; b=${todo_last[$st]}
      [ "$a" = "$shot_first" ] && [ "$b" = "$shot_last" ] || args+=(--frames "$a-$b")
    fi
    [ "$st" = bake ] && [ "$resume" = 1 ] && args+=(--resume)
    [ "$st" = render ] && [ "$plots" = 0 ] && args+=(--no-plots)
    "$bin/$st" "${args[@]}"
    ran=$((ran + 1))
  done
  secs=$(awk -v a="$t0" -v b="$EPOCHREALTIME" 'BEGIN{printf "%.1f", b-a}')
  echo "pipeline: $ran stage(s) ran, $skipped up to date, ${secs}s"
  exit 0
fi

# ---- farm: one sbatch script per job, chained with afterok -----------------------------------------
# The binaries know nothing of Slurm. Every path in a script is absolute, so a job runs from any folder
# of a filesystem the nodes share with this machine.
abs() { (cd "$(dirname "$1")" && echo "$(pwd)/$(basename "$1")"); }
scene_abs=$(abs "$scene")
shot_dir=$(dirname "$("$bin/bake" --print-out-dir "$scene")")
mkdir -p "$shot_dir"
shot_dir=$(cd "$shot_dir" && pwd)
out_root=$(dirname "$shot_dir")
shot=$(basename "$shot_dir")
cache_root="${DRENCH_CACHE:-cache}"
mkdir -p "$cache_root"
cache_root=$(cd "$cache_root" && pwd)
farm_dir="$shot_dir/farm"
read -r first last < <("$bin/bake" --print-frames "$scene")
nframes=$((last - first + 1))
ntasks=$(( (nframes + chunk - 1) / chunk ))

if [ "$dry_run" = 0 ]; then
  for t in sbatch squeue; do
    command -v "$t" >/dev/null || die "'$t' not found: install the Slurm client (Debian package slurm-client) and point SLURM_CONF at the farm's slurm.conf"
  done
  mkdir -p "$farm_dir/logs"
fi

# header NAME TIME ARRAY [#SBATCH LINE...]: the #SBATCH lines (sbatch reads them only before the first
# command, so every one is here), then the commands every drench job starts with.
header() {
  local name="$1" limit="$2" array="$3"
  shift 3
  echo "#!/bin/bash"
  echo "#SBATCH --job-name=$name"
  if [ -n "$array" ]; then
    echo "#SBATCH --array=$array"
    echo "#SBATCH --output=$farm_dir/logs/%x-%A_%a.out"
  else
    echo "#SBATCH --output=$farm_dir/logs/%x-%j.out"
  fi
  echo "#SBATCH --time=$limit"
  [ -n "$partition" ] && echo "#SBATCH --partition=$partition"
  [ -n "$account" ] && echo "#SBATCH --account=$account"
  [ -n "$cpus" ] && echo "#SBATCH --cpus-per-task=$cpus"
  local line
  for line in "$@"; do echo "#SBATCH $line"; done
  echo "# written by drench pipeline.sh for scene $scene_abs"
  echo "set -uo pipefail"
  echo "export DRENCH_OUT='$out_root' DRENCH_CACHE='$cache_root'"
  echo 'threads=${SLURM_CPUS_PER_TASK:-${SLURM_CPUS_ON_NODE:-1}}'
}

# The frame range of this array task: chunks of $chunk frames from the shot's first frame.
chunk_lines() {
  echo "first=\$(( $first + SLURM_ARRAY_TASK_ID * $chunk )); last=\$(( first + $chunk - 1 ))"
  echo "[ \$last -gt $last ] && last=$last"
}

script_precompute() {
  header "$1" "$time_limit" ""
  echo "exec '$bin/precompute' '$scene_abs' -j \"\$threads\""
}

# The bake asks Slurm for SIGUSR1 $signal_lead s before its time limit, passes it to bake (which finishes
# the frame in progress, checkpoints and exits 3) and requeues itself; the requeued job resumes.
script_bake() {
  header "$1" "$bake_time_limit" "" "--signal=B:USR1@$signal_lead" --requeue --open-mode=append
  echo "resume=($([ "$resume" = 1 ] && echo --resume))" # a stopped bake whose checkpoint is usable continues
  echo "[ \"\${SLURM_RESTART_COUNT:-0}\" -gt 0 ] && resume=(--resume)"
  echo "'$bin/bake' '$scene_abs' -j \"\$threads\" \"\${resume[@]}\" &"
  echo "pid=\$!"
  echo "trap 'echo \"drench: time limit near: asking bake to checkpoint\"; kill -USR1 \$pid' USR1"
  echo "wait \$pid; rc=\$?"
  echo "while kill -0 \$pid 2>/dev/null; do wait \$pid; rc=\$?; done"
  echo "if [ \$rc -eq 3 ]; then"
  echo "  echo \"drench: bake checkpointed; requeueing job \$SLURM_JOB_ID to resume\""
  echo "  scontrol requeue \"\$SLURM_JOB_ID\" && exit 0"
  echo "fi"
  echo "exit \$rc"
}

script_frames() { # STAGE NAME
  header "$2" "$time_limit" "0-$((ntasks - 1))"
  chunk_lines
  local opt=""
  [ "$1" = render ] && opt=" --no-plots"
  echo "exec '$bin/$1' '$scene_abs' --frames \"\$first-\$last\" -j \"\$threads\"$opt"
}

script_finish() { # STAGE NAME
  header "$2" "$time_limit" ""
  local opt=""
  [ "$1" = render ] && [ "$plots" = 0 ] && opt=" --no-plots"
  echo "exec '$bin/$1' '$scene_abs' --finish -j \"\$threads\"$opt"
}

# submit NAME SCRIPT_TEXT DEPENDENCY: prints the job id. A job of the same name (same shot, stage and
# key) already queued or running is reused, so submitting twice does not duplicate work.
submit() {
  local name="$1" text="$2" dep="$3" file="$farm_dir/$1.sbatch"
  local dep_args=()
  [ -n "$dep" ] && dep_args=(--dependency="afterok:$dep" --kill-on-invalid-dep=yes)
  if [ "$dry_run" = 1 ]; then
    printf '%s\n' "----- sbatch --parsable ${dep_args[*]} $file" "$text" >&3
    echo "<$name>"
    return
  fi
  local existing
  existing=$(squeue -h -n "$name" -o "%F" 2>/dev/null | head -1 || true)
  if [ -n "$existing" ]; then
    echo "  $name is already queued as job $existing; not submitted again" >&2
    echo "$existing"; return
  fi
  printf '%s\n' "$text" > "$file.tmp.$$" && mv "$file.tmp.$$" "$file"
  # shellcheck disable=SC2086
  sbatch --parsable "${dep_args[@]}" $sbatch_extra "$file" | cut -d';' -f1
}

exec 3>&1 # the dry run prints the scripts here while job ids are captured from submit's stdout
dep=""
graph=()
submitted=0
for st in "${stages[@]}"; do
  key_var="key_$st"; key=${!key_var}
  if [ -z "${reason_of[$st]}" ]; then
    echo "$st: up to date (key $key), not submitted"; continue
  fi
  name="drench-$shot-$st-${key:0:12}"
  case "$st" in
    precompute)
      # One job per asset that needs precomputation; until an element needs one, a single job records
      # the stage's MANIFEST.
      id=$(submit "$name" "$(script_precompute "$name")" "$dep")
      graph+=("precompute: job $id${dep:+ after $dep}") ;;
    bake)
      id=$(submit "$name" "$(script_bake "$name")" "$dep")
      graph+=("bake: job $id${dep:+ after $dep} (requeues itself near its time limit and resumes)") ;;
    mesh|render)
      arr=$(submit "$name" "$(script_frames "$st" "$name")" "$dep")
      id=$(submit "$name-finish" "$(script_finish "$st" "$name-finish")" "$arr")
      graph+=("$st: array job $arr ($ntasks tasks of $chunk frames)${dep:+ after $dep}, then job $id after $arr (--finish)") ;;
  esac
  echo "$st: submitted (${reason_of[$st]})"
  dep=$id
  submitted=$((submitted + 1))
done
if [ "$dry_run" = 0 ] && [ ${#graph[@]} -gt 0 ]; then
  printf '%s\n' "${graph[@]}" > "$farm_dir/jobs.txt"
fi
[ ${#graph[@]} -gt 0 ] && printf '  %s\n' "${graph[@]}"
note=""
[ "$dry_run" = 1 ] && note=" (dry run: nothing submitted)"
echo "pipeline: $submitted stage(s) submitted to Slurm$note; last job ${dep:-none}"
