#!/usr/bin/env bash
# Renders the afterimage corpus (corpus/scenes.py) with Blender Cycles into a cache
# directory: OUT/SCENE/{input,reference}/frame_####.exr, OUT/SCENE/meta.json.
#
#   corpus/render.sh [--out DIR] [--size WxH] [--frames N] [--ref-spp N] [--threads N]
#                    [--scenes a,b,...] [--half] [--force]
#
# Defaults: --out ${XDG_CACHE_HOME:-~/.cache}/afterimage-corpus, --size 320x180,
# --frames 24, --ref-spp 256, --threads 2, every scene. A scene whose meta.json and last
# reference frame exist is skipped (unless --force), so an interrupted run resumes.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
out="${XDG_CACHE_HOME:-$HOME/.cache}/afterimage-corpus"
size=320x180
frames=24
ref_spp=256
threads=2
scenes=""
half=""
force=0
blender="${BLENDER:-blender}"

while [ $# -gt 0 ]; do
  case "$1" in
    --out) out="$2"; shift 2 ;;
    --size) size="$2"; shift 2 ;;
    --frames) frames="$2"; shift 2 ;;
    --ref-spp) ref_spp="$2"; shift 2 ;;
    --threads) threads="$2"; shift 2 ;;
    --scenes) scenes="$2"; shift 2 ;;
    --half) half="--half"; shift ;;
    --force) force=1; shift ;;
    -h|--help) sed -n '2,12p' "$0"; exit 0 ;;
    *) echo "render.sh: unknown option $1 (see --help)" >&2; exit 2 ;;
  esac
done

width="${size%x*}"
height="${size#*x}"
if [ -z "$scenes" ]; then
  scenes="fence,fence_gi,pan,movers,hdr,texture,foliage,light,gi,cut"
fi
IFS=',' read -r -a list <<< "$scenes"

mkdir -p "$out"
start=$(date +%s)
n=${#list[@]}
k=0
for scene in "${list[@]}"; do
  k=$((k + 1))
  dir="$out/$scene"
  last=$(printf '%s/reference/frame_%04d.exr' "$dir" "$frames")
  if [ "$force" = 0 ] && [ -f "$dir/meta.json" ] && [ -f "$last" ]; then
    echo "[$k/$n] $scene: already in $dir, skipped"
    continue
  fi
  t0=$(date +%s)
  echo "[$k/$n] $scene: ${width}x${height}, $frames frames, reference $ref_spp spp ..."
  "$blender" -b --factory-startup --python "$here/scenes.py" -- \
    --scene "$scene" --out "$dir" --width "$width" --height "$height" \
    --frames "$frames" --ref-spp "$ref_spp" --threads "$threads" $half \
    > "$dir.log" 2>&1 || { echo "$scene failed, see $dir.log" >&2; tail -20 "$dir.log" >&2; exit 1; }
  t1=$(date +%s)
  elapsed=$((t1 - start))
  echo "[$k/$n] $scene: done in $((t1 - t0)) s (total $((elapsed / 60)) min $((elapsed % 60)) s)"
done
total=$(( $(date +%s) - start ))
echo "corpus in $out: $n scenes, ${width}x${height}, $frames frames, $ref_spp spp references; took $((total / 60)) min $((total % 60)) s"
