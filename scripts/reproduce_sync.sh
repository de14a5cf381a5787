#!/usr/bin/env bash
# Keep what a multi-session `nue reproduce` run has proved in git, and put it back on a fresh machine.
#   bash scripts/reproduce_sync.sh save     RUN -> results/reproduce/run (recipe, stage markers, the
#                                           best.pt and selection summary of every finished model, records)
#   bash scripts/reproduce_sync.sh commit   save, then commit the store but its best.pt files (git commit -- <store>,
#                                           nothing else staged is committed): recipe, markers, records, selections,
#                                           hashes; COMMIT_CHECKPOINTS=1 (with CHECKPOINTS=1) commits the best.pt files
#                                           too, each once, when its run has finished
#   bash scripts/reproduce_sync.sh autosave [MINUTES]  commit every MINUTES (default 20), until killed: a session
#                                           that ends without warning keeps what its evaluation had recorded
#   bash scripts/reproduce_sync.sh restore  results/reproduce/run -> RUN; without the demonstrations
#                                           (8.7 GB, never committed) and with a model still to train, the collect
#                                           marker is dropped, so that model finds its data again (the collection is
#                                           seeded: the same manifest hash, which `nue train --resume` checks); once
#                                           every model is trained the marker stays and evaluation goes on
# RUN is the run's folder (`nue reproduce --out`; default runs/reproduce in the repository; a relative RUN is taken
# from the current folder). STORE is where it is kept (default results/reproduce/run in the repository holding this
# script; a relative STORE is taken from the repository). Each finished run's best.pt sha256 is kept (best.sha256);
# CHECKPOINTS=0 keeps only that, not the file: restore then drops the markers of the runs whose best.pt is missing,
# so they train again (a run retrained on another CPU may round differently; its evaluation records are then refused,
# naming the method).
# Then rerun the same `nue reproduce` command: finished stages are kept, the rest continues.
set -euo pipefail
self=$(realpath "$0")
root=$(dirname "$(dirname "$self")")
run=${RUN:-$root/runs/reproduce}
case "$run" in /*) ;; *) run=$PWD/$run ;; esac
cd "$root"
store=${STORE:-results/reproduce/run}
checkpoints=${CHECKPOINTS:-1}
case "${1:-}" in
  save)
    mkdir -p "$store/stages" "$store/records"
    cp "$run/recipe.json" "$store/"
    # the store mirrors the run: a stage the run has not finished (again) is not kept as finished
    for marker in "$store"/stages/*.json; do
      [ -e "$marker" ] || continue
      stage=$(basename "$marker")
      [ -e "$run/stages/$stage" ] && continue
      rm "$marker"
      case "$stage" in train__*) name=${stage#train__}; rm -rf "$store/runs/${name%.json}" ;; esac
    done
    cp "$run"/stages/*.json "$store/stages/"
    for marker in "$run"/stages/train__*.json; do
      [ -e "$marker" ] || continue
      model=$(basename "$marker" .json); model=${model#train__}
      mkdir -p "$store/runs/$model"
      (cd "$run/runs/$model" && sha256sum best.pt) > "$store/runs/$model/best.sha256"
      [ "$checkpoints" = 1 ] && cp "$run/runs/$model/best.pt" "$store/runs/$model/"
      for f in "$run/runs/$model"/selection*; do [ -e "$f" ] && cp "$f" "$store/runs/$model/"; done
    done
    [ -d "$run/records" ] && cp -r "$run/records/." "$store/records/"  # with records/explore/
    # but not the lock a running evaluation holds beside its records (nue.output_lock; git ignores it)
    find "$store/records" -name '.*.lock' -delete
    # in the repository, a file git would not commit is not saved (session 1's best.pt files were lost to a .gitignore
    # pattern)
    case "$store" in /*) ;; *)
      ignored=$(git ls-files --others --ignored --exclude-standard -- "$store")
      if [ -n "$ignored" ]; then echo "error: $store: git ignores $ignored" >&2; exit 2; fi ;;
    esac
    du -sh "$store" ;;
  restore)
    mkdir -p "$run"
    cp -rn "$store"/. "$run"/
    # the houses (data/scenes, never committed) are made again on a fresh machine; the stage keeps intact ones
    [ -e "$run/stages/scenes.json" ] && rm "$run/stages/scenes.json" && echo "scenes: houses checked again"
    # a training run whose best.pt was not kept (CHECKPOINTS=0) trains again
    for marker in "$run"/stages/train__*.json; do
      [ -e "$marker" ] || continue
      name=$(basename "$marker" .json); name=${name#train__}
      if [ ! -f "$run/runs/$name/best.pt" ]; then
        # and the old run's selection goes: its records name snapshots the new run will have made differently
        rm -f "$marker" "$run/runs/$name"/selection* "$run/runs/$name/best.sha256"
        echo "train/$name: no best.pt kept, trains again"
      fi
    done
    # the demonstrations are needed again only while a training run is still to train (the recipe's runs: every seed)
    runs=$(python -c "import json, sys; from nue.recipes import get_recipe
print(' '.join(r.name for r in get_recipe(json.load(open(sys.argv[1]))['recipe']['name']).training_runs()))" "$run/recipe.json")
    left=0
    for name in $runs; do [ -e "$run/stages/train__$name.json" ] || left=1; done
    if [ "$left" = 1 ]; then
      for marker in "$run"/stages/collect.json "$run"/stages/collect__*.json; do
        [ -e "$marker" ] || continue
        split=$(basename "$marker" .json); split=${split#collect}; split=${split#__}
        demos=$run/demos${split:+_$split}
        if [ ! -d "$demos" ]; then rm -f "$marker"; echo "collect${split:+/$split}: $demos missing, collected again"; fi
      done
    fi
    ls "$run/stages" ;;
  commit)
    RUN=$run bash "$self" save > /dev/null
    n=$(find "$store/records" -name '*.jsonl' -exec cat {} + | wc -l)  # 0 before the first evaluation
    # best.pt (CHECKPOINTS=1) is committed only with COMMIT_CHECKPOINTS=1: each file once, when its run has finished
    # (a run spanning machines keeps its trained models); otherwise by hand when wanted
    paths=("$store")
    [ "${COMMIT_CHECKPOINTS:-0}" = 1 ] || paths+=(":(exclude)$store/runs/*/best.pt")
    git add -- "${paths[@]}"
    if git diff --cached --quiet -- "$store"; then echo "nothing new"; exit 0; fi
    git commit -q -m "reproduce run: $(ls "$store"/stages | wc -l) stages done, $n episodes recorded (evaluation and exploration; sync.sh)" \
      -- "${paths[@]}"
    git log --oneline -1 ;;
  autosave)
    minutes=${2:-20}
    while true; do
      sleep $((60 * minutes))
      # a failed commit is reported on stderr (with its error line) and retried at the next one, never fatal
      RUN=$run bash "$self" commit > /dev/null || echo "autosave: commit failed at $(date -u '+%F %H:%M UTC')" >&2
    done ;;
  *) echo "usage: $0 save|restore|commit|autosave [MINUTES]" >&2; exit 2 ;;
esac
