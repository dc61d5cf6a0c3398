"""The paper's experiments, baselines and the checks of identified models."""
