"""MuJoCo ground truth: batched rollouts, randomized datasets, planted (undeclared) effects."""
