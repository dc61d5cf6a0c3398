"""Multi-step identification through the differentiable engine: windows, Levenberg-Marquardt fits."""

from tensegrity_env.lazy import lazy_exports

__all__, __getattr__ = lazy_exports(
    __name__,
    {
        "TrajectoryIdentifier": "identification.trajectory.identifier",
        "ParamVector": "identification.trajectory.param_vector",
        "WindowFit": "identification.trajectory.windowed_fit",
        "Windows": "identification.trajectory.windows",
        "cut_windows": "identification.trajectory.windows",
        "WindowedProblem": "identification.trajectory.windowed_problem",
        "FitOptions": "identification.trajectory.windowed_problem",
        "fit": "identification.trajectory.windowed_problem",
        "window_schedule": "identification.trajectory.windows",
        "SlackRegression": "identification.trajectory.slack_regression",
        "find_touchdowns": "identification.trajectory.touchdown",
        "search_contact": "identification.trajectory.touchdown",
        "airborne_mask": "identification.trajectory.airborne",
    },
)
