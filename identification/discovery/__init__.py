"""The residual loop: find what the model misses, name the effect, add it, refit."""
