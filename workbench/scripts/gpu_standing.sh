#!/usr/bin/env bash
# The standing training run on a GPU lease (docs/training.md, "On a GPU lease"). Here, after `make install`:
#   bash ../shared/gpu/prepare.sh; rm -f .device/wheels/{uv,ruff,py_spy}-*.whl    # dev tools: 54 MiB left
#   cp workbench/scripts/gpu_standing.sh .device/project/
# A device call carries the working tree too, 64 MiB in all, and the tracked tree is larger than the wheels leave room
# for: keep the saves and pictures out of it while the calls run, and put them back after (sparse checkout keeps
# what is modified):
#   git sparse-checkout set --no-cone '/*' '!/docs/' '!/checkpoints/' '!/lerobot_instant_policy/assets/checkpoints/'
# then two device calls, each within 30 s of the last:
#   carry .device/wheels:   bash .device/wheels/on-device.sh wheels
#   (here: git sparse-checkout set --no-cone '/*' '!/docs/' '!/checkpoints/stream/best/'
#    '!/lerobot_instant_policy/assets/checkpoints/'   -- the last save travels, the rest stays out)
#   carry .device/project:  bash .device/project/gpu_standing.sh 430 120
# and here: git sparse-checkout disable; cat OUT/save.tar.part-* > F/save.tar; cp OUT/standing.json F/;
#   python -m workbench.cli.standing accept F
# The run continues checkpoints/stream/last on cuda with the CPU cores generating (its deadline and validation
# window in seconds, defaults 430 and 120; a save every 250 steps, about 35 s at batch 64 there, so the stop loses
# little); its save comes back in parts under 16 MiB. The shipped checkpoint is copied
# from the installed wheel (the tree leaves it out) so the device compares the save with it. If the run has not ended
# by 570 s of the call, the latest complete LeRobot save is packed instead (raw.tar.part-*), to be validated here.
deadline=${1:-430}
validate=${2:-120}
bash .device/project/on-device.sh project >/dev/null && source .device/project/on-device.sh env || exit 1
nvidia-smi -L
shipped=lerobot_instant_policy/assets/checkpoints/instant_policy
[ -f $shipped/model.safetensors ] || { mkdir -p $shipped && cp -r /tmp/site/$shipped/. $shipped/; }
mkdir -p outputs/gpu_standing
setsid nohup python3 -m workbench.cli.standing run --device cuda --generator-device cpu --generators 13 \
  --val-workers 1 --batch-size 64 --save-freq 250 --deadline-s "$deadline" --validate-s "$validate" --out outputs/gpu_standing/out \
  > outputs/gpu_standing/wrapper.log 2>&1 &
while [ $SECONDS -lt 570 ] && [ ! -f outputs/gpu_standing/out/standing.json ]; do sleep 3; done
echo "ended at ${SECONDS}s"
if [ -f outputs/gpu_standing/out/standing.json ]; then
  split -b 15M outputs/gpu_standing/out/save.tar "$OUT/save.tar.part-"
  cp outputs/gpu_standing/out/standing.json "$OUT/"
else
  latest=$(ls -d outputs/standing/run-*/checkpoints/0* 2>/dev/null | sort | tail -1)
  echo "no record by 570 s; packing ${latest:-nothing}"
  [ -n "$latest" ] && tar cf - -C "$latest" pretrained_model training_state | split -b 15M - "$OUT/raw.tar.part-"
fi
cp outputs/gpu_standing/wrapper.log "$OUT/"
grep -ho "smp/s:[0-9.]*\|updt_s:[0-9.]*" outputs/standing/run-*.log | tail -4
