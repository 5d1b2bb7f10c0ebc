#!/bin/bash
# Plans a tiled bake, submits one array task per tile and the merge after all of them.
# Usage: deploy/slurm/submit.sh SCENE PLAN_DIR BAKE_DIR X,Y,Z [prt plan flags...]
# e.g.   deploy/slurm/submit.sh /shared/Sponza.gltf /shared/plan /shared/out 4,4,1 --res 256
set -euo pipefail
if [ "$#" -lt 4 ]; then
    echo "usage: $0 SCENE PLAN_DIR BAKE_DIR X,Y,Z [prt plan flags...]" >&2
    exit 2
fi
scene=$1 plan=$2 out=$3 tiles=$4
shift 4
here=$(cd "$(dirname "$0")" && pwd)
prt plan "$scene" --tiles "$tiles" --out "$plan" "$@"
IFS=, read -r tx ty tz <<<"$tiles"
count=$((tx * ty * tz))
export PLAN_DIR=$plan BAKE_DIR=$out
array=$(sbatch --parsable --export=ALL --array=0-$((count - 1)) "$here/prt-bake.sbatch")
merge=$(sbatch --parsable --export=ALL --dependency=afterok:"$array" "$here/prt-merge.sbatch")
echo "tiles: job $array (array 0-$((count - 1))), merge: job $merge"
