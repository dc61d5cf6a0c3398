"""The paper's experiments, baselines and the checks of identified models."""

from tensegrity_env.lazy import lazy_exports

__all__, __getattr__ = lazy_exports(
    __name__,
    {
        "run_paper": "identification.experiments.paper",
        "run_efficiency": "identification.experiments.efficiency",
        "long_horizon_errors": "identification.experiments.long_horizon",
        "DROP_TOLERANCE": "identification.experiments.drop_check",
        "run_case": "identification.experiments.planted_table",
    },
)
