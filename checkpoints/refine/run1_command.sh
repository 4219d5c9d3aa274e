#!/bin/bash
# usage: refine_cmd.sh OUTDIR STEPS SAVE_FREQ SEED
OUT=$1; STEPS=$2; SAVE=$3; SEED=${4:-7000}
exec env OMP_NUM_THREADS=1 HF_HUB_OFFLINE=1 .venv/bin/lerobot-ip-train \
  --stream.config=configs/generate/stream_bounded_mixed.json --stream.seed=$SEED \
  --stream.samples_per_task=8 --stream.tasks_per_render=1 --stream.surface_samples=4096 \
  --pool --pool.capacity=1000 --pool.min_tasks=16 --pool.generators=1 --pool.generator_threads=1 --pool.device=cpu \
  --policy.path=checkpoints/stream/best/pretrained_model --policy.optimizer_lr=2e-4 \
  --policy.refine_fraction=0.5 --policy.replay_per_object=true --policy.push_to_hub=false \
  --batch_size=8 --steps=$STEPS --wandb.enable=false --num_workers=0 --policy.device=cpu \
  --output_dir=$OUT --save_freq=$SAVE --log_freq=10 --average.decay=0.99975
