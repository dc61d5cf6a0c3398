"""One-step identification by linear regression: design matrix, constrained solve, estimators."""
