#!/bin/bash
# Issue 11 item 3: the same demonstrations stored float16 and compact; one NUE trained on each at equal samples.
# Run from anywhere: it works in the repository holding it (its .venv, data/, runs/c11/); about 2 hours on 2 cores.
# Results: results/storage/ (README.md there), discussed in docs/history/benchmarks.md.
set -e
cd "$(dirname "$0")/.."
export OMP_NUM_THREADS=1 LP_NUM_THREADS=1 PYTHONHASHSEED=0
N=.venv/bin/nue
S=runs/c11/stages.txt
mkdir -p runs/c11
st() { echo "$(date -u +%H:%M:%S) $*" >> $S; }
st collect_f16 start
$N collect --out data/demos_explore_f16 --episodes-per-bin 6 --heldout-per-bin 1 --noise 0.3 --expert explore \
   --workers 2 --rgbd-bits 0 --i-cog-bits 0 > runs/c11/collect_f16.log 2>&1
st convert start
$N convert data/demos_explore_f16 --out data/demos_explore_c > runs/c11/convert.log 2>&1
st train start
for v in f16:data/demos_explore_f16 c:data/demos_explore_c; do
  name=${v%%:*}; d=${v#*:}
  $N train --data $d --out runs/c11/nue_$name --model nue --steps 3000 --batch-size 64 --time-budget 0 \
     --eval-every 750 --precision fp32 --map-dropout 0.2 --select closed_loop --select-candidates 2 \
     > runs/c11/train_$name.log 2>&1 &
done
wait
st eval start
for name in f16 c; do
  $N eval -c nue_$name=runs/c11/nue_$name/best.pt --out runs/c11/eval_$name.jsonl --workers 1 > runs/c11/eval_$name.log 2>&1 &
done
wait
st done
