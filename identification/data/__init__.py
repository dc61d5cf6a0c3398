"""Measured and generated motion as data: the dataset format, end caps to rod states."""

from tensegrity_env.lazy import lazy_exports

__all__, __getattr__ = lazy_exports(
    __name__,
    {
        "SPLITS": "identification.data.dataset",
        "Dataset": "identification.data.dataset",
        "GroundTruth": "identification.data.dataset",
        "Split": "identification.data.dataset",
        "check_dataset": "identification.data.dataset",
        "read_dataset": "identification.data.dataset",
        "read_ground_truth": "identification.data.dataset",
        "write_dataset": "identification.data.dataset",
        "METHODS": "identification.data.end_caps",
        "RodAxes": "identification.data.end_caps",
        "SmoothedStates": "identification.data.end_caps",
        "dataset_from_end_caps": "identification.data.end_caps",
        "measured_rod_states": "identification.data.end_caps",
        "odd_window": "identification.data.end_caps",
        "rod_states_from_nodes": "identification.data.end_caps",
        "smooth_nodes": "identification.data.end_caps",
        "smooth_rod_states": "identification.data.end_caps",
        "with_measured_states": "identification.data.end_caps",
    },
)
