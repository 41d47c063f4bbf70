"""The model families, one sub-package each: `vicsek` (M1), `flocking` (M2, with M3's
obstacles and navigation), `formation` (M4). Each family's `kernel` module registers its
per-step kernel (`kernels.model.MODULES` names them); `fused` holds its small-N batch.

Nothing is imported here: the engine imports only the family a scenario needs.
"""
