"""Cucker–Smale flocking (IEEE TAC 2007): law.py, the per-step kernel, the fused batch."""
