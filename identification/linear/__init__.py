"""One-step identification by linear regression: design matrix, constrained solve, estimators."""

from tensegrity_env.lazy import lazy_exports

__all__, __getattr__ = lazy_exports(
    __name__,
    {
        "NotFittedError": "identification.linear.regression",
        "ParameterRow": "identification.linear.regression",
        "SpringRodIdentifier": "identification.linear.regression",
        "evaluate_params": "identification.linear.regression",
        "parse_anchor": "identification.linear.regression",
        "ExtendedIdentifier": "identification.linear.extended",
        "evaluate_model": "identification.linear.extended",
        "parse_anchors": "identification.linear.smoothed",
        "smoothed_regression": "identification.linear.smoothed",
        "Solution": "identification.linear.solve",
        "solve_constrained": "identification.linear.solve",
        "ParameterLayout": "identification.linear.design",
        "TransitionFeatures": "identification.linear.features",
        "transition_features": "identification.linear.features",
    },
)
