"""Bounds of the render options that the HTTP routes check as query parameters and the
drawing code checks again (importable without h5py or matplotlib, like errors.py)."""

from __future__ import annotations

# Movie frame rates. The encoder gets the rate as a fraction with a denominator of at most
# 10^6 (imageio-ffmpeg), so a rate near 0 became "-r 0" and ffmpeg refused it; below
# one frame per 10 s a movie is a slide show, which snapshots serve better.
MIN_FPS = 0.1
MAX_FPS = 120.0
