#!/bin/bash
# Submits a planned tiled bake to Slurm: one array task per tile not yet finished
# (prt-bake.sbatch), then the merge (prt-merge.sbatch) once that array has ended.
#
#   prt plan SCENE --tiles X,Y,Z [prt bake's knobs] --out PLAN_DIR
#   deploy/slurm/submit.sh PLAN_DIR BAKE_DIR [MERGE_FLAG...] [-- SBATCH_OPTION... [--merge SBATCH_OPTION...]]
#   deploy/slurm/submit.sh PLAN_DIR BAKE_DIR --distributed-merge [--sweeps K] [-- ...]
#   deploy/slurm/submit.sh --resume PLAN_DIR [-- SBATCH_OPTION... [--merge SBATCH_OPTION...]]
#
# MERGE_FLAGs go to `prt merge` (e.g. --stream --sweeps 2). `--distributed-merge [--sweeps K]`
# runs the streamed merge as distributed work instead: per stage (coarse, sweep-1..sweep-K,
# coefficients) an array of map tasks over the tiles (prt-merge-map.sbatch), then its reduce
# (prt-merge-reduce.sbatch), each after the one before (afterany); the last reduce writes
# BAKE_DIR, the bytes `prt merge --stream --sweeps K` writes. Options after `--` go to every
# job's sbatch, those after `--merge` to the merge's jobs only (a later option wins). Without
# -c/--cpus-per-task a job asks for the CPUs of the partition's largest node, at most 8, so that
# it never pends on a node too small. Logs: PLAN_DIR/logs/slurm-tile-INDEX.log and
# slurm-merge.log, appended by every attempt. The submission (BAKE_DIR, flags, options) and the
# job ids are kept in PLAN_DIR/slurm/: --resume submits, with them and any new options after
# them, the tiles not finished for the plan (failed, cancelled, never run) and the merge again
# (a new submission of the same plan does the same with new flags and options). Both refuse
# while a job they submitted for this plan is queued or running.
set -euo pipefail
usage() {
    echo "usage: $0 PLAN_DIR BAKE_DIR [MERGE_FLAG...] [-- SBATCH_OPTION... [--merge SBATCH_OPTION...]]" >&2
    echo "       $0 --resume PLAN_DIR [-- SBATCH_OPTION... [--merge SBATCH_OPTION...]]" >&2
    exit 2
}
fail() {
    echo "error: $*" >&2
    exit 1
}
here=$(cd "$(dirname "$0")" && pwd)
resume=false
if [ "${1:-}" = --resume ]; then
    resume=true
    shift
fi
[ "$#" -ge 1 ] || usage
[ -f "$1/plan.json" ] || fail "$1 holds no plan.json: write the plan with prt plan first"
plan=$(cd "$1" && pwd)
shift
state=$plan/slurm
args_file=$state/submit.args
jobs_file=$state/jobs

# flags=(prt merge's), then from `-- ... [--merge ...]` both=(sbatch options for both jobs)
# merge=(for the merge only).
flags=() both=() merge=()
take_options() {
    [ "$#" -eq 0 ] && return
    [ "$1" = -- ] || usage
    shift
    local into=both opt
    for opt in "$@"; do
        if [ "$opt" = -- ]; then
            into=both
        elif [ "$opt" = --merge ]; then
            into=merge
        elif [ "$into" = both ]; then
            both+=("$opt")
        else
            merge+=("$opt")
        fi
    done
}
if $resume; then
    [ -f "$args_file" ] || fail "nothing was submitted for $plan ($args_file is missing): run $0 PLAN_DIR BAKE_DIR"
    [ "$#" -eq 0 ] || [ "$1" = -- ] || usage
    mapfile -d '' -t saved <"$args_file"
    set -- "${saved[@]}" "$@"
fi
[ "$#" -ge 1 ] || usage
bake=$1
shift
case $bake in /*) ;; *) bake=$PWD/$bake ;; esac
while [ "$#" -gt 0 ] && [ "$1" != -- ]; do
    flags+=("$1")
    shift
done
# On --resume: the saved `-- ... --merge ...`, then the new one.
take_options "$@"

# A second submission while the first runs would trace tiles twice and merge twice.
if [ -f "$jobs_file" ]; then
    ours=$({ grep -oE "(tiles|merge|maps|reduce)=[0-9]+" "$jobs_file" || true; } | cut -d= -f2 | sort -u)
    queued=$(squeue -h -o '%F' | sort -u)
    active=$(comm -12 <(echo "$ours") <(echo "$queued") | paste -sd, -)
    [ -z "$active" ] || fail "jobs $active of this plan are still queued or running: wait for them, or scancel them, then run $0 --resume $plan"
fi

# `--cpus-per-task=N` with N the CPUs of the largest node of the job's partition, at most 8;
# nothing when the options or the sbatch file already ask for CPUs.
cpus_for() {
    local file=$1 partition=${SBATCH_PARTITION:-} next=false opt most
    shift
    grep -qE '^#SBATCH[[:space:]]+(-c|--cpus-per-task)' "$file" && return
    for opt in "$@"; do
        if $next; then
            partition=$opt next=false
            continue
        fi
        case $opt in
            -c | -c* | --cpus-per-task | --cpus-per-task=*) return ;;
            -p | --partition) next=true ;;
            -p*) partition=${opt#-p} ;;
            --partition=*) partition=${opt#--partition=} ;;
        esac
    done
    if [ -n "$partition" ]; then
        most=$(sinfo -h -N -p "$partition" -o '%c' | sort -n | tail -1)
    else # the default partition, which sinfo marks with a *
        most=$(sinfo -h -N -o '%c %P' | awk '$2 ~ /\*$/ { print $1 }' | sort -n | tail -1)
    fi
    [ -n "$most" ] || fail "sinfo lists no node in ${partition:-the default partition}: pass -p PARTITION or -c CPUS after --"
    echo "--cpus-per-task=$((most < 8 ? most : 8))"
}

# --distributed-merge [--sweeps K]: no other merge flag.
distributed=false sweeps=2
if printf '%s\n' "${flags[@]}" | grep -qx -- --distributed-merge; then
    distributed=true
    rest=("${flags[@]}")
    set -- "${rest[@]}"
    while [ "$#" -gt 0 ]; do
        case $1 in
            --distributed-merge) ;;
            --sweeps) sweeps=${2:?--sweeps needs a number}; shift ;;
            --sweeps=*) sweeps=${1#--sweeps=} ;;
            *) fail "with --distributed-merge the only merge flag is --sweeps K (got $1)" ;;
        esac
        shift
    done
    case $sweeps in '' | *[!0-9]*) fail "--sweeps $sweeps is not a number" ;; esac
    # Tiles: the product of the plan's "counts".
    counts=($(tr -d ' \n' <"$plan/plan.json" | grep -oE '"counts":\[[0-9]+,[0-9]+,[0-9]+\]' |
        head -1 | grep -oE '[0-9]+'))
    [ "${#counts[@]}" -eq 3 ] || fail "$plan/plan.json has no tile counts"
    ntiles=$((counts[0] * counts[1] * counts[2]))
fi

# The jobs run `prt` from the PATH exported with them (--export=ALL).
command -v prt >/dev/null || fail "prt is not on PATH (the jobs get this shell's PATH)"
unfinished=$(prt bake-tile "$plan" --unfinished)
mkdir -p "$plan/logs" "$state"
printf '%s\0' "$bake" "${flags[@]}" -- "${both[@]}" --merge "${merge[@]}" >"$args_file"
export PLAN_DIR=$plan BAKE_DIR=$bake
dependency=()
if [ -n "$unfinished" ]; then
    cpus=$(cpus_for "$here/prt-bake.sbatch" "${both[@]}")
    tiles=$(sbatch --parsable --export=ALL --array="$unfinished" \
        --output="$plan/logs/slurm-tile-%a.log" --open-mode=append \
        ${cpus:+"$cpus"} "${both[@]}" "$here/prt-bake.sbatch")
    tiles=${tiles%%;*}
    echo "$(date -u +%FT%TZ) tiles=$tiles array=$unfinished" >>"$jobs_file"
    # afterany, not afterok: after a failed tile the merge runs, finds the tile unfinished and
    # fails naming it, instead of pending forever (DependencyNeverSatisfied).
    dependency=(--dependency=afterany:"$tiles")
    echo "tiles $unfinished: job $tiles"
else
    echo "every tile is finished"
fi
if $distributed; then
    cpus=$(cpus_for "$here/prt-merge-map.sbatch" "${both[@]}" "${merge[@]}")
    stages=(coarse)
    for ((k = 1; k <= sweeps; k++)); do stages+=("sweep-$k"); done
    stages+=(coefficients)
    for stage in "${stages[@]}"; do
        env=--export=ALL,STAGE=$stage,SWEEPS=$sweeps
        maps=$(sbatch --parsable "$env" "${dependency[@]}" --array="0-$((ntiles - 1))" \
            --output="$plan/logs/slurm-map-$stage-%a.log" --open-mode=append \
            ${cpus:+"$cpus"} "${both[@]}" "${merge[@]}" "$here/prt-merge-map.sbatch")
        maps=${maps%%;*}
        job=$(sbatch --parsable "$env" --dependency=afterany:"$maps" \
            --output="$plan/logs/slurm-reduce-$stage.log" --open-mode=append \
            ${cpus:+"$cpus"} "${both[@]}" "${merge[@]}" "$here/prt-merge-reduce.sbatch")
        job=${job%%;*}
        echo "$(date -u +%FT%TZ) maps=$maps reduce=$job stage=$stage" >>"$jobs_file"
        echo "$stage: maps job $maps, reduce job $job"
        dependency=(--dependency=afterany:"$job")
    done
    echo "merge: job $job (the coefficients' reduce), writing $bake"
    echo "logs: $plan/logs/slurm-*.log; after a failure: $0 --resume $plan"
    exit 0
fi
cpus=$(cpus_for "$here/prt-merge.sbatch" "${both[@]}" "${merge[@]}")
job=$(sbatch --parsable --export=ALL "${dependency[@]}" \
    --output="$plan/logs/slurm-merge.log" --open-mode=append \
    ${cpus:+"$cpus"} "${both[@]}" "${merge[@]}" "$here/prt-merge.sbatch" "${flags[@]}")
job=${job%%;*}
echo "$(date -u +%FT%TZ) merge=$job" >>"$jobs_file"
echo "merge: job $job${dependency:+ once job ${tiles} has ended}, writing $bake"
echo "logs: $plan/logs/slurm-*.log; after a failure: $0 --resume $plan"
