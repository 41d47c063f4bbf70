"""M1: the Vicsek rule and the JLM angle rules (average, laplacian, leader). `kernel` is
the per-step path (parallel over agents), `fused` the small-N batch."""
