"""identification: spring-rod parameters from motion (rod states or measured end caps).

Subpackages by job: :mod:`.data` (dataset format, end caps to rod states),
:mod:`.simulation` (MuJoCo ground truth), :mod:`.linear` (one-step regression),
:mod:`.trajectory` (multi-step fits from end caps), :mod:`.discovery` (the residual
loop), :mod:`.report`, :mod:`.experiments`, :mod:`.commands` (CLI subcommands). The
names below are imported on first use.
"""

from tensegrity_env.lazy import lazy_exports

__all__, __getattr__ = lazy_exports(
    __name__,
    {
        "Dataset": "identification.data.dataset",
        "read_dataset": "identification.data.dataset",
        "read_ground_truth": "identification.data.dataset",
        "write_dataset": "identification.data.dataset",
        "dataset_from_end_caps": "identification.data.end_caps",
        "with_measured_states": "identification.data.end_caps",
        "GenerateSpec": "identification.simulation.generate",
        "generate_dataset": "identification.simulation.generate",
        "SpringRodIdentifier": "identification.linear.regression",
        "ExtendedIdentifier": "identification.linear.extended",
        "TrajectoryIdentifier": "identification.trajectory.identifier",
    },
)
