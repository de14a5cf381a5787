#!/usr/bin/env bash
# Keep what a multi-session `nue reproduce` run has proved in git, and put it back on a fresh machine.
#   bash scripts/reproduce_sync.sh save     RUN -> results/reproduce/run (recipe, stage markers, the
#                                           best.pt and selection summary of every finished model, records)
#   bash scripts/reproduce_sync.sh autosave [MINUTES]  save every MINUTES (default 20) and commit the records and
#                                           stage markers only (git commit -- <those paths>), until killed: a session
#                                           that ends without warning keeps what its evaluation had recorded
#   bash scripts/reproduce_sync.sh restore  results/reproduce/run -> RUN; without the demonstrations
#                                           (8.7 GB, never committed) and with a model still to train, the collect
#                                           marker is dropped, so that model finds its data again (the collection is
#                                           seeded: the same manifest hash, which `nue train --resume` checks); once
#                                           every model is trained the marker stays and evaluation goes on
# RUN is the run's folder (`nue reproduce --out`; default runs/reproduce in the repository; a relative RUN is taken
# from the current folder); results/reproduce/run is in the repository holding this script, wherever it is called from.
# Then rerun the same `nue reproduce` command: finished stages are kept, the rest continues.
set -euo pipefail
self=$(realpath "$0")
root=$(dirname "$(dirname "$self")")
run=${RUN:-$root/runs/reproduce}
case "$run" in /*) ;; *) run=$PWD/$run ;; esac
cd "$root"
store=results/reproduce/run
case "${1:-}" in
  save)
    mkdir -p "$store/stages" "$store/records"
    cp "$run/recipe.json" "$store/"
    cp "$run"/stages/*.json "$store/stages/"
    for marker in "$run"/stages/train__*.json; do
      [ -e "$marker" ] || continue
      model=$(basename "$marker" .json); model=${model#train__}
      mkdir -p "$store/runs/$model"
      cp "$run/runs/$model/best.pt" "$store/runs/$model/"
      for f in "$run/runs/$model"/selection*; do [ -e "$f" ] && cp "$f" "$store/runs/$model/"; done
    done
    for f in "$run"/records/*.jsonl; do [ -e "$f" ] && cp "$f" "$store/records/"; done
    # a file git would not commit is not saved (session 1's best.pt files were lost to a .gitignore pattern)
    ignored=$(git ls-files --others --ignored --exclude-standard -- "$store")
    if [ -n "$ignored" ]; then echo "error: $store: git ignores $ignored" >&2; exit 2; fi
    du -sh "$store" ;;
  restore)
    mkdir -p "$run"
    cp -rn "$store"/. "$run"/
    # the demonstrations are needed again only while a model is still to train
    models=$(python3 -c "import json, sys; print(len(json.load(open(sys.argv[1]))['recipe']['models']))" "$run/recipe.json")
    trained=$(find "$run/stages" -name 'train__*.json' | wc -l)
    if [ ! -d "$run/demos" ] && [ "$trained" -lt "$models" ]; then rm -f "$run/stages/collect.json"; fi
    ls "$run/stages" ;;
  autosave)
    minutes=${2:-20}
    while true; do
      sleep $((60 * minutes))
      RUN=$run bash "$self" save > /dev/null || continue
      n=$(cat "$store"/records/*.jsonl 2>/dev/null | wc -l)
      git add "$store/records" "$store/stages" 2>/dev/null || continue
      git commit -q -m "reproduce run: evaluation records so far ($n runs recorded, sync.sh autosave)" -- "$store/records" "$store/stages" > /dev/null 2>&1 || true
    done ;;
  *) echo "usage: $0 save|restore|autosave [MINUTES]" >&2; exit 2 ;;
esac
