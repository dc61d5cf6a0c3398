"""Tables and figures shared by identification, discovery and the experiments."""

from tensegrity_env.lazy import lazy_exports

__all__, __getattr__ = lazy_exports(
    __name__,
    {
        "group_errors": "identification.report.tables",
        "parameter_table": "identification.report.tables",
        "relative_errors": "identification.report.tables",
        "plot_rollout_comparison": "identification.report.plots",
        "save_figure": "identification.report.plots",
    },
)
