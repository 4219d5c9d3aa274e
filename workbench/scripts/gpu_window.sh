#!/usr/bin/env bash
# One device window for the GPU campaign (docs/training.md, "Run on one H100"). Here, after `make install`:
#   bash ../shared/gpu/prepare.sh
#   rm -f .device/wheels/{metaworld,mujoco,pyopengl,glfw}-*.whl           # not needed to train; over 64 MiB with them
#   mkdir -p .device/av && mv .device/wheels/av-*.whl .device/av/ && cp workbench/scripts/gpu_window.sh .device/project/
# then three device calls, each within 30 s of the last:
#   carry .device/wheels:  bash .device/wheels/on-device.sh wheels
#   carry .device/av:      python3 -m pip install -q --no-index --no-deps --target /tmp/site-av .device/av/*.whl && cp -r /tmp/site-av/. /tmp/site/
#   carry .device/project: bash .device/project/gpu_window.sh 540
# The last trains configs/train_rounds/gpu_campaign.json in the background and, at the deadline (seconds since it
# started, default 540), packs the latest checkpoint, the action error and the logs into $OUT.
deadline=${1:-540}
bash .device/project/on-device.sh project >/dev/null && source .device/project/on-device.sh env || exit 1
nvidia-smi -L
export OMP_NUM_THREADS=1
out=outputs/gpu_campaign
mkdir -p outputs
# workbench/ (not in the wheel) comes with the working tree the device call copies; run it from the repository root
setsid nohup python3 -m workbench.cli.train_rounds --config .device/project/configs/train_rounds/gpu_campaign.json \
  > outputs/train_rounds.log 2>&1 &
while [ $SECONDS -lt "$deadline" ] && [ ! -f $out/summary.json ]; do sleep 10; done
# the run's own choice of checkpoint (train_rounds.Layout): the latest complete one, never one still being written
checkpoint=$(python3 -c "import sys; from workbench.train_rounds import Layout; print(Layout(sys.argv[1]).latest_checkpoint() or '')" $out)
echo "latest checkpoint: ${checkpoint:-none} at ${SECONDS}s"
[ -n "$checkpoint" ] && tar czf "$OUT/checkpoint.tgz" -C "$checkpoint" pretrained_model training_state/training_step.json
cp outputs/train_rounds.log $out/state.json $out/summary.json $out/action_error.json "$OUT"/ 2>/dev/null
tar czf "$OUT/logs.tgz" -C $out logs
grep -h "smp/s" $out/logs/train-*.log | tail -2
