"""Data that ships with zipon (package data, read with :mod:`importlib.resources`): ``clip_text/`` holds the
CLIP ViT-B/32 text embeddings of the LVIS names that the simulated perception models use (its README gives
source and licence)."""
