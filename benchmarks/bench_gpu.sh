#!/usr/bin/env bash
# The map stage where a GPU exists: frames/s of each real encoder (LSeg ViT-L/16, MaskCLIP ViT-B/32,
# ConceptFusion; random weights saved to files, the compute of trained ones, nothing downloaded), the device,
# and the share of the stage's wall time spent outside the encoder (frames read and decoded, projection,
# fusion, the store written). One JSON line per encoder and precision (bench_batch.py --real-encoders).
#
# On a GPU: 64 frames at 640x480 per encoder, in fp32 and under bf16 autocast (about 5-8 min on one GPU,
# most of it LSeg and the upstream stages built once). Without one: the same path on the CPU on 16 frames
# (LSeg on 1), fp32 only, to show it runs. Override with FRAMES, LSEG_FRAMES, PRECISIONS, DEVICE, PYTHON.
#
#     benchmarks/bench_gpu.sh            # or: DEVICE=cuda:1 PRECISIONS="fp32 fp16" benchmarks/bench_gpu.sh
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-.venv/bin/python}
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" HF_HUB_OFFLINE=1
if "$PY" -c "import sys, torch; sys.exit(0 if torch.cuda.is_available() else 1)"; then
  DEVICE=${DEVICE:-cuda:0}; FRAMES=${FRAMES:-64}; LSEG_FRAMES=${LSEG_FRAMES:-64}; PRECISIONS=${PRECISIONS:-"fp32 bf16"}
else
  DEVICE=${DEVICE:-cpu}; FRAMES=${FRAMES:-16}; LSEG_FRAMES=${LSEG_FRAMES:-1}; PRECISIONS=${PRECISIONS:-fp32}
fi
ROOT=$(mktemp -d -t zipon-bench-gpu-XXXXXX)
trap 'rm -rf "$ROOT"' EXIT
"$PY" -c "import torch; print('{\"bench\": \"gpu\", \"kind\": \"device\", \"device\": \"$DEVICE\", \"name\": \"' + (torch.cuda.get_device_name(0) if torch.cuda.is_available() else 'cpu') + '\", \"torch\": \"' + torch.__version__ + '\"}')"
for precision in $PRECISIONS; do  # the upstream stages are built once in ROOT and reused
  "$PY" benchmarks/bench_batch.py --real-encoders --keep "$ROOT" --frames "$FRAMES" --lseg-frames "$LSEG_FRAMES" \
    --encoders lseg maskclip conceptfusion --device "$DEVICE" --precision "$precision"
done
