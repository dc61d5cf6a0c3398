"""Hyperparameter search with Optuna: search spaces, the trial objective, the study."""
